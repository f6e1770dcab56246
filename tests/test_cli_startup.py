"""``bodyhealth --help`` and the parser load no heavy package: a command's stack is imported when it runs.

Checked in a fresh interpreter, since this test process has numpy, torch and the service loaded
already. The assertion is on the set of imported modules, which does not depend on how busy the machine
is; the wall time it saves (seconds on a loaded 2-core machine) follows from it.
"""

from __future__ import annotations

import json
import subprocess
import sys

#: Packages that cost hundreds of milliseconds to seconds to import, and no help text needs.
HEAVY = ("torch", "mujoco", "scipy", "sklearn", "distributed", "dask", "sqlalchemy", "fastapi", "matplotlib")

_PROBE = """
import json, sys
from cli.main import build_parser
parser = build_parser()
parser.format_help()
sub = next(a for a in parser._actions if a.dest == "command")
for p in sub.choices.values():
    p.format_help()
print(json.dumps(sorted(sys.modules)))
"""


def _loaded_after(code: str) -> set[str]:
    """Every module (dotted name) loaded once ``code`` ran in a fresh interpreter."""
    out = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, check=True, timeout=120
    )
    return set(json.loads(out.stdout.splitlines()[-1]))


def _heavy(modules: set[str]) -> list[str]:
    return sorted({m.split(".")[0] for m in modules} & set(HEAVY))


def test_building_the_parser_and_every_help_imports_nothing_heavy() -> None:
    loaded = _loaded_after(_PROBE)
    assert _heavy(loaded) == []
    assert not any(m.startswith("bench.") for m in loaded)


def test_help_lists_every_command_and_loads_nothing_heavy() -> None:
    code = (
        "import json, runpy, sys\n"
        "sys.argv = ['bodyhealth', '--help']\n"
        "try:\n    runpy.run_module('cli', run_name='__main__')\n"
        "except SystemExit as e:\n    assert e.code == 0, e.code\n"
        "print(json.dumps(sorted({m.split('.')[0] for m in sys.modules})))\n"
    )
    out = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, check=True, timeout=120
    )
    assert _heavy(set(json.loads(out.stdout.splitlines()[-1]))) == []
    for command in ("robots", "simulate", "topology", "kinematics", "diff", "serve", "db", "bench"):
        assert f"    {command}" in out.stdout, command


def test_a_benchmark_is_loaded_when_its_command_line_is_parsed() -> None:
    code = _PROBE.replace(
        "parser.format_help()\n",
        "parser.format_help()\nparser.parse_args(['bench', 'import', '--seconds', '5'])\n",
        1,
    )
    assert "bench.import_" in _loaded_after(code)
    from cli.main import build_parser

    args = build_parser().parse_args(["bench", "import", "--seconds", "5"])
    assert args.seconds == 5.0 and callable(args.func)


def test_the_cli_method_names_are_the_estimators() -> None:
    from bodyschema.estimate import METHODS
    from cli.commands.diff import METHODS as CLI_METHODS

    assert CLI_METHODS == METHODS
