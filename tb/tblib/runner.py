"""Build and run one cocotb bench on GHDL from a pytest function.

Every flow reads the same compile order, ``rtl/files.f``; everything is compiled into the
``canopen_master`` VHDL library. Each call gets its own build directory named after the pytest
node (test name plus parameters), so ``pytest -n auto`` can run benches in parallel.

Generics go to GHDL as ``-g<NAME>=<value>`` and, because cocotb cannot read generics on GHDL,
also to the Python side as ``PARAM_<NAME>`` environment variables (see :func:`param`).

Every GHDL command runs in its own process group, killed as a whole when the call is
interrupted (pytest's ``timeout``, Ctrl-C): ``ghdl -r`` starts the simulation binary as its own
child, and killing only ``ghdl`` (what ``subprocess.run`` does) leaves the simulation running
without a parent, holding a core for the rest of the suite.
"""

from __future__ import annotations

import os
import re
import signal
import subprocess
from collections.abc import Mapping
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
RTL_DIR = ROOT / "rtl"
SIM_BUILD = ROOT / "build" / "sim"
HDL_LIBRARY = "canopen_master"


def rtl_sources(files_f: Path = RTL_DIR / "files.f") -> list[Path]:
    """Source files in compile order, from ``rtl/files.f``."""
    out: list[Path] = []
    for line in files_f.read_text().splitlines():
        line = line.split("#", 1)[0].strip()
        if line:
            out.append(files_f.parent / line)
    return out


def build_dir_for(name: str) -> Path:
    safe = re.sub(r"[^A-Za-z0-9_.-]+", "_", name).strip("_")
    return SIM_BUILD / safe


def param(name: str, default: int | None = None) -> int:
    """Read a generic value handed to the bench as ``PARAM_<NAME>``."""
    value = os.environ.get(f"PARAM_{name}")
    if value is None:
        if default is None:
            raise KeyError(f"PARAM_{name} not set: run this bench through its pytest wrapper")
        return default
    return int(value)


def _ghdl_runner():
    """cocotb's GHDL runner with the process-group handling of the module docstring."""
    from cocotb_tools.runner import Ghdl

    class GroupKillingGhdl(Ghdl):
        def _execute_cmds(self, cmds, cwd, stdout=None) -> None:
            __tracebackhide__ = True
            for cmd in cmds:
                self.log.info("Running command %s in directory %s", " ".join(cmd), cwd)
                stderr = None if stdout is None else subprocess.STDOUT
                proc = subprocess.Popen(cmd, cwd=cwd, env=self.env, stdout=stdout,
                                        stderr=stderr, start_new_session=True)
                try:
                    rc = proc.wait()
                except BaseException:
                    os.killpg(proc.pid, signal.SIGKILL)
                    proc.wait()
                    raise
                if rc != 0:
                    raise RuntimeError(f"Command failed with return code: {rc}")

    return GroupKillingGhdl()


def run_cocotb(
    *,
    toplevel: str,
    module: str,
    name: str,
    parameters: Mapping[str, int] | None = None,
    extra_env: Mapping[str, str] | None = None,
    testcase: str | list[str] | None = None,
    stop_time_ms: float = 1000.0,
    waves: bool | None = None,
    ieee_asserts: str = "disable-at-0",
) -> Path:
    """Build ``toplevel`` from ``rtl/files.f`` and run the cocotb tests in ``module``.

    A failing cocotb test fails the calling pytest test. ``stop_time_ms`` is a safety net
    against GHDL not ending the simulation (GHDL issue #3064); every cocotb test also carries
    its own timeout. ``waves`` defaults to the ``WAVES`` environment variable (``make waves``).
    ``ieee_asserts`` is GHDL's ``--ieee-asserts`` (numeric_std metavalue warnings): benches whose
    bus functional models drive 'X' on idle inputs (cocotb-bus's Avalon master) use "disable".
    Returns the build directory (which holds ``<toplevel>.ghw`` when waves were requested).
    """
    os.environ.setdefault("GHDL_BACKEND", "llvm")
    parameters = dict(parameters or {})
    if waves is None:
        waves = os.environ.get("WAVES", "0") not in ("", "0")
    build_dir = build_dir_for(name)
    build_dir.mkdir(parents=True, exist_ok=True)
    env = {f"PARAM_{k}": str(v) for k, v in parameters.items()}
    env.update(extra_env or {})
    env.setdefault("COCOTB_LOG_LEVEL", os.environ.get("COCOTB_LOG_LEVEL", "INFO"))

    runner = _ghdl_runner()
    runner.build(
        sources=rtl_sources(),
        hdl_library=HDL_LIBRARY,
        hdl_toplevel=toplevel,
        build_args=["--std=08"],
        build_dir=build_dir,
        always=True,
    )
    runner.test(
        test_module=module,
        hdl_toplevel=toplevel,
        hdl_toplevel_library=HDL_LIBRARY,
        build_dir=build_dir,
        test_args=["--std=08"],
        plusargs=[f"--stop-time={int(stop_time_ms * 1000)}us", f"--ieee-asserts={ieee_asserts}"],
        parameters=parameters,
        extra_env=env,
        testcase=testcase,
        waves=waves,
        results_xml=str(build_dir / "results.xml"),
    )
    if waves:
        wave = build_dir / f"{toplevel}.ghw"
        with open(SIM_BUILD / "last_waves.txt", "a") as f:
            f.write(f"{wave}\n")
    return build_dir
