# =================================================================================================
# Title    : quartus_project.tcl
# Project  : canopen_master - open-source CANopen master IP core (MCP2510 over SPI)
# SPDX-License-Identifier: Apache-2.0
# =================================================================================================
# Creates the Quartus project of canopen_master_top as a stand-alone top on a Cyclone III
# EP3C80F484C8 (a compile and timing check of the core; for a board design use the Platform
# Designer flow of docs/integration.md):
#
#   quartus_sh -t scripts/quartus_project.tcl [project_dir]      (default: build/quartus)
#   quartus_sh --flow compile <project_dir>/canopen_master       (then: compile it)
#
# The VHDL files and their order come from rtl/files.f (parsed here: one file per line, '#'
# starts a comment), all in library canopen_master, as VHDL-93 (VHDL_1993: the RTL keeps to
# VHDL-93 because the Quartus versions for Cyclone III read VHDL-2008 only in part). Constraints:
# constraints/ep3c80_reference.sdc (clock, I/O delays, false paths on the top's ports) and
# constraints/ep3c80_reference_pins.tcl (PLACEHOLDER pin locations, see that file).
# Paths are written relative to the project directory, so the project can be moved with the
# repository. Not run on this project's machines (no Quartus there): tb/test_integration_kit.py
# runs it in tclsh with stub Quartus commands and checks the assignments it makes.
# =================================================================================================

package require ::quartus::project

set repo_root    [file normalize [file join [file dirname [info script]] ..]]
set project_name canopen_master
set top_entity   canopen_master_top
set hdl_library  canopen_master
set family       "Cyclone III"
set device       EP3C80F484C8

if {[llength $argv] > 0} {
    set project_dir [file normalize [lindex $argv 0]]
} else {
    set project_dir [file join $repo_root build quartus]
}

# Path of $target relative to $base (both absolute), with "/" separators as Quartus writes them.
proc relative_path {target base} {
    set t [file split [file normalize $target]]
    set b [file split [file normalize $base]]
    set n 0
    while {$n < [llength $t] && $n < [llength $b] && [lindex $t $n] eq [lindex $b $n]} {
        incr n
    }
    set parts {}
    for {set i $n} {$i < [llength $b]} {incr i} {
        lappend parts ..
    }
    set parts [concat $parts [lrange $t $n end]]
    if {[llength $parts] == 0} {
        return .
    }
    return [join $parts /]
}

# Source files of rtl/files.f in compile order (absolute paths); a missing file is an error.
proc read_files_f {files_f} {
    set fh [open $files_f r]
    set text [read $fh]
    close $fh
    set files {}
    foreach line [split $text "\n"] {
        set hash [string first "#" $line]
        if {$hash >= 0} {
            set line [string range $line 0 [expr {$hash - 1}]]
        }
        set line [string trim $line]
        if {$line eq ""} {
            continue
        }
        set path [file join [file dirname $files_f] $line]
        if {![file isfile $path]} {
            error "rtl/files.f lists $line, but $path does not exist"
        }
        lappend files $path
    }
    if {[llength $files] == 0} {
        error "rtl/files.f lists no files"
    }
    return $files
}

file mkdir $project_dir
set here [pwd]
cd $project_dir
if {[project_exists $project_name]} {
    project_open $project_name
} else {
    project_new $project_name
}

set_global_assignment -name FAMILY $family
set_global_assignment -name DEVICE $device
set_global_assignment -name TOP_LEVEL_ENTITY $top_entity
set_global_assignment -name VHDL_INPUT_VERSION VHDL_1993
set_global_assignment -name PROJECT_OUTPUT_DIRECTORY output_files

# a re-run must not keep files that left rtl/files.f
remove_all_global_assignments -name VHDL_FILE
remove_all_global_assignments -name SDC_FILE
foreach vhd [read_files_f [file join $repo_root rtl files.f]] {
    set_global_assignment -name VHDL_FILE [relative_path $vhd $project_dir] -library $hdl_library
}
set_global_assignment -name SDC_FILE \
    [relative_path [file join $repo_root constraints ep3c80_reference.sdc] $project_dir]

# PLACEHOLDER pin locations and the I/O standards (see the file)
source [file join $repo_root constraints ep3c80_reference_pins.tcl]

export_assignments
project_close
cd $here
puts "quartus_project.tcl: $project_dir/$project_name.qpf ($device, top $top_entity)"
