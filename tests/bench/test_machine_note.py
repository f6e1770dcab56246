"""The machine line every bench file carries names the CPU's family and model beside its name, which a
hypervisor may cut to "AMD EPYC"."""

from __future__ import annotations

import os
import platform
from pathlib import Path

from bench import machine_note

PY = f"Python {platform.python_version()}"


def test_family_and_model_follow_the_name_from_the_first_processor(tmp_path: Path) -> None:
    info = tmp_path / "cpuinfo"
    first = "processor\t: 0\ncpu family\t: 25\nmodel\t\t: 1\nmodel name\t: AMD EPYC\n"
    info.write_text(first + "\nprocessor\t: 1\ncpu family\t: 23\nmodel\t\t: 49\nmodel name\t: other\n")
    assert machine_note(str(info)) == f"{os.cpu_count()} cores, AMD EPYC (family 25, model 1), {PY}"


def test_a_cpuinfo_without_numbers_gives_the_name_alone(tmp_path: Path) -> None:
    info = tmp_path / "cpuinfo"
    info.write_text("processor\t: 0\nmodel name\t: Some CPU\n")
    assert machine_note(str(info)) == f"{os.cpu_count()} cores, Some CPU, {PY}"
    assert machine_note(str(tmp_path / "absent")).startswith(f"{os.cpu_count()} cores, ")
