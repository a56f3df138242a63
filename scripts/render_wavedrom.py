#!/usr/bin/env python3
"""Render every docs/wavedrom/*.json (WaveDrom source) to the SVG committed beside it."""

from pathlib import Path

import wavedrom

ROOT = Path(__file__).resolve().parents[1]

for src in sorted((ROOT / "docs" / "wavedrom").glob("*.json")):
    wavedrom.render(src.read_text()).saveas(str(src.with_suffix(".svg")))
    print(f"rendered {src.with_suffix('.svg').relative_to(ROOT)}")
