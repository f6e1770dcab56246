"""The figures quoted in README.md and docs/*.md are the ones their bench files hold.

``bench.docs`` renders every marked figure block from its bench file; these tests fail when a
block differs from what the bench file says now, when a doc citing a bench file carries no block from
it, when a bench figure sits outside the blocks, and they show on copies that the check does catch an
edited bench file or doc (so it cannot pass vacuously). A few figures that went stale by hand before are
also recomputed here straight from the bench files, independently of the renderer.
"""

from __future__ import annotations

import argparse
import json
import re
import shutil
from pathlib import Path

import pytest

from bench import BENCHMARKS, docs

REPO = Path(__file__).resolve().parents[2]
BENCH = REPO / "docs" / "bench"

#: The least number of figure blocks each doc must carry (the figure sets that went stale by hand).
MIN_BLOCKS = {
    "README.md": 10,
    "docs/topology.md": 4,
    "docs/sim2real.md": 5,
    "docs/transports.md": 1,
    "docs/simulators.md": 1,
    "docs/store.md": 1,
    "docs/algebra.md": 1,
    "docs/recording-format.md": 1,
}


#: Numbers a doc may quote outside the blocks although a block renders them too: facts of the data set,
#: not results of a run.
NOT_RESULTS = {"docs/sim2real.md": {"285.7"}}  # BROAD's sample rate, stated with the data set


def _copy(tmp_path: Path) -> Path:
    """README.md, docs/*.md and the bench files (no plots) under a fresh root."""
    root = tmp_path / "repo"
    (root / "docs").mkdir(parents=True)
    shutil.copy(REPO / "README.md", root / "README.md")
    for p in (REPO / "docs").glob("*.md"):
        shutil.copy(p, root / "docs" / p.name)
    shutil.copytree(BENCH, root / "docs" / "bench", ignore=shutil.ignore_patterns("*.png"))
    return root


def _outside(text: str) -> str:
    return re.sub(r"<!-- fig:.*?<!-- /fig -->", "", text, flags=re.S)


def test_every_figure_block_matches_its_bench_file() -> None:
    problems = docs.check(REPO)
    assert not problems, "run `make docs` (bodyhealth bench docs):\n" + "\n".join(problems)


def test_the_known_figure_sets_are_covered() -> None:
    found = docs.blocks(REPO)
    per_doc: dict[str, int] = {}
    for b in found:
        per_doc[b.doc] = per_doc.get(b.doc, 0) + 1
    for doc, least in MIN_BLOCKS.items():
        assert per_doc.get(doc, 0) >= least, f"{doc}: {per_doc.get(doc, 0)} figure blocks, want ≥ {least}"
    readme_sources = {Path(b.source).stem for b in found if b.doc == "README.md"}
    for bench in ("algebra", "topology", "scaling", "sim", "store", "ingest", "sim2real", "gravity"):
        assert bench in readme_sources, f"README.md has no figure block from docs/bench/{bench}.*"
    # every block names the machine and the command behind it
    for b in found:
        body = " ".join(b.body.split())
        assert "Python 3." in body and "`bodyhealth bench" in body, f"{b.doc}: fig:{b.id} names no machine"
    assert "docs" in BENCHMARKS and BENCHMARKS[-1] == "docs", "docs renders last, after every benchmark"


def test_docs_citing_a_bench_file_carry_a_block_from_it() -> None:
    cite = re.compile(r"(?:docs/)?bench/([a-z0-9_]+)(?:\.md|\.json|\.png|/|\*)")
    sources: dict[str, set[str]] = {}
    for b in docs.blocks(REPO):
        stem = Path(b.source).name.split(".")[0] if b.source != docs.BENCH else "*"
        sources.setdefault(b.doc, set()).add(stem)
        if "sim2real/" in b.source:
            sources[b.doc].add("sim2real")
    names = ["README.md", *(f"docs/{p.name}" for p in sorted((REPO / "docs").glob("*.md")))]
    for name in names:
        cited = set(cite.findall((REPO / name).read_text(encoding="utf-8")))
        missing = cited - sources.get(name, set())
        assert not missing, f"{name} cites docs/bench/{sorted(missing)} but has no figure block from it"


def _distinctive(text: str) -> set[str]:
    """Numbers in rendered text specific enough to be a measurement: 3+ significant digits."""
    out = set()
    text = re.sub(r"Python\s+[\d.]*\d", "", text)  # the machine line's version is no measurement
    for m in re.finditer(r"(?<![\w.,/-])\d[\d,]*\.\d+|(?<![\w.,/-])\d{1,3}(?:,\d{3})+", text):
        digits = m.group(0).replace(",", "").replace(".", "").lstrip("0")
        if len(digits) >= 3:
            out.add(m.group(0))
    return out


def test_no_bench_figure_is_quoted_outside_a_block() -> None:
    """A doc quotes no figure of the benches it cites outside the blocks (where it could go stale)."""
    rendered = docs.render(REPO)
    cite = re.compile(r"(?:docs/)?bench/([a-z0-9_]+)")
    names = ["README.md", *(f"docs/{p.name}" for p in sorted((REPO / "docs").glob("*.md")))]
    for name in names:
        text = (REPO / name).read_text(encoding="utf-8")
        cited = set(cite.findall(text))
        mine = [
            rendered[(f.doc, f.id)]
            for f in docs.FIGURES
            if f.doc == name or Path(f.source).name.split(".")[0] in cited
        ]
        numbers = set().union(set(), *(_distinctive(t) for t in mine)) - NOT_RESULTS.get(name, set())
        rest = _outside(text)
        stray = sorted(n for n in numbers if re.search(rf"(?<![\w.,]){re.escape(n)}(?![\w,]|\.\d)", rest))
        assert not stray, f"{name} quotes bench figures outside a figure block: {stray}"


# --- figures that went stale by hand, recomputed here from the bench files -------------------------


def _block(doc: str, fig: str) -> str:
    found = [b.body for b in docs.blocks(REPO, [doc]) if b.id == fig]
    assert len(found) == 1, f"{doc}: fig:{fig} not found once"
    return found[0]


def _md_rows(text: str, first: str) -> list[list[str]]:
    lines = text.splitlines()
    i = next(k for k, ln in enumerate(lines) if ln.startswith(f"| {first} |"))
    rows = []
    for ln in lines[i + 2 :]:
        if not ln.startswith("|"):
            break
        rows.append([c.strip() for c in ln.strip("|").split("|")])
    return rows


def test_transports_ingest_rates_are_the_bench_files() -> None:
    block = _block("docs/transports.md", "ingest")
    rows = {r[0]: r for r in _md_rows((BENCH / "ingest.md").read_text(encoding="utf-8"), "path")}
    for path in (
        "serial pty (emulator process)",
        "CAN slcan pty (emulator process)",
        "CAN FD slcan pty (emulator process)",
    ):
        for cell in rows[path][1:5]:
            assert cell in block, f"{path}: {cell} from docs/bench/ingest.md is not in docs/transports.md"


def test_simulators_rates_are_the_bench_files() -> None:
    block = _block("docs/simulators.md", "sim")
    text = (BENCH / "sim.md").read_text(encoding="utf-8")
    cpu = [int(r[-1].rstrip("×")) for r in _md_rows(text, "robot") if r[0].startswith("paper-")]
    assert f"{min(cpu)}–{max(cpu)}×" in block
    for r in _md_rows(text, "farm"):
        assert r[-1] in block, f"farm row {r}: {r[-1]} not in docs/simulators.md"


def test_sim2real_time_offset_gains_span_the_fifteen_reports() -> None:
    files = sorted((BENCH / "sim2real").glob("*/discrepancy.json"))
    assert len(files) == 15
    gains = []
    for f in files:
        causes = json.loads(f.read_text(encoding="utf-8"))["causes"]
        gains += [c["gain"] for c in causes if c["effect"] == "time_offset"]
    assert len(gains) == 15
    span = f"held-out gain {min(gains):.2f}–{max(gains):.2f}"
    assert span in " ".join(_block("docs/sim2real.md", "results").split())


def test_readme_names_each_bench_files_machine() -> None:
    block = _block("README.md", "bench-machines")
    for md in sorted(BENCH.glob("*.md")):
        m = re.search(r"(?:Machine|Measured on): (.+?Python [\d.]*\d)", md.read_text(encoding="utf-8"))
        assert m is not None, f"{md.name} names no machine"
        row = next(ln for ln in block.splitlines() if ln.startswith(f"| `{md.stem}` |"))
        assert m.group(1) in row, f"README gives {md.stem} another machine than {md.name}: {row}"
    assert "Xeon" in next(ln for ln in block.splitlines() if ln.startswith("| `algebra` |"))


def test_topology_figures_are_the_bench_files() -> None:
    block = _block("docs/topology.md", "topology")
    for r in json.loads((BENCH / "topology.json").read_text(encoding="utf-8")):
        net = r["network"]
        row = next(ln for ln in block.splitlines() if ln.startswith(f"| {r['robot']} |"))
        assert f"{net['true_min']:.3f} / {net['false_max']:.3f}" in row
        assert f"{net['exact']}/{net['runs']}" in row


def test_service_doc_claims_no_bench_figure() -> None:
    """The encoder-offset figures in docs/service.md come from tests; no benchmark measures them."""
    text = (REPO / "docs" / "service.md").read_text(encoding="utf-8")
    assert not docs.blocks(REPO, ["docs/service.md"])
    assert "docs/bench" not in text and "bench/" not in text
    assert "no benchmark measures the detection rate" in " ".join(text.split())


# --- the check can fail ---------------------------------------------------------------------------


def test_copy_passes_then_an_edited_bench_file_fails(tmp_path: Path) -> None:
    root = _copy(tmp_path)
    assert docs.check(root) == []
    path = root / "docs" / "bench" / "ingest.json"
    data = json.loads(path.read_text(encoding="utf-8"))
    row = next(r for r in data["rows"] if r["path"] == "serial pty (emulator process)")
    row["frames_per_s"] += 1000
    path.write_text(json.dumps(data), encoding="utf-8")
    problems = docs.check(root)
    assert any(p.startswith("docs/transports.md: fig:ingest differs") for p in problems), problems
    assert any(p.startswith("README.md: fig:ingest differs") for p in problems), problems


def test_an_edited_sim2real_report_fails(tmp_path: Path) -> None:
    root = _copy(tmp_path)
    path = root / "docs" / "bench" / "sim2real" / "07_undisturbed_fast_rotation_B" / "discrepancy.json"
    data = json.loads(path.read_text(encoding="utf-8"))
    next(c for c in data["causes"] if c["effect"] == "time_offset")["gain"] = 0.95
    path.write_text(json.dumps(data), encoding="utf-8")
    problems = docs.check(root)
    assert any(p.startswith("docs/sim2real.md: fig:results differs") for p in problems), problems


def test_a_changed_machine_line_fails(tmp_path: Path) -> None:
    root = _copy(tmp_path)
    path = root / "docs" / "bench" / "algebra.md"
    path.write_text(
        path.read_text(encoding="utf-8").replace("Intel(R) Xeon(R)", "AMD EPYC"), encoding="utf-8"
    )
    problems = docs.check(root)
    assert any(p.startswith("README.md: fig:bench-machines differs") for p in problems), problems
    assert any(p.startswith("docs/algebra.md: fig:algebra differs") for p in problems), problems


def test_an_edited_doc_fails_and_update_restores_it(tmp_path: Path) -> None:
    root = _copy(tmp_path)
    path = root / "docs" / "transports.md"
    text = path.read_text(encoding="utf-8")
    assert "| 25,866 |" in text
    path.write_text(text.replace("| 25,866 |", "| 25,900 |"), encoding="utf-8")
    assert [p.split(":\n")[0] for p in docs.check(root)] == [
        "docs/transports.md: fig:ingest differs from docs/bench/ingest.json"
    ]
    with pytest.raises(SystemExit) as exc:
        docs.run(argparse.Namespace(check=True, root=root))
    assert exc.value.code == 1
    assert docs.update(root) == ["docs/transports.md"]
    assert path.read_text(encoding="utf-8") == text
    assert docs.check(root) == []


def test_missing_unknown_and_mislabelled_blocks_fail(tmp_path: Path) -> None:
    root = _copy(tmp_path)
    sim = root / "docs" / "simulators.md"
    sim.write_text(_outside(sim.read_text(encoding="utf-8")), encoding="utf-8")
    store = root / "docs" / "store.md"
    store.write_text(
        store.read_text(encoding="utf-8").replace(
            "source=docs/bench/store.json", "source=docs/bench/store.md"
        )
        + "\n<!-- fig:made-up source=docs/bench/sim.md -->\n1.0\n<!-- /fig -->\n",
        encoding="utf-8",
    )
    problems = docs.check(root)
    assert "docs/simulators.md: fig:sim is missing (source docs/bench/sim.md)" in problems
    assert any(p.startswith("docs/store.md: fig:made-up is not a known figure") for p in problems)
    assert any(p.startswith("docs/store.md: fig:store says source=docs/bench/store.md") for p in problems)


def test_a_bench_file_without_a_machine_line_fails(tmp_path: Path) -> None:
    root = _copy(tmp_path)
    path = root / "docs" / "bench" / "sim.md"
    path.write_text(re.sub(r"Machine: .*\n", "", path.read_text(encoding="utf-8")), encoding="utf-8")
    problems = docs.check(root)
    assert any("fig:sim cannot be rendered" in p and "names no machine" in p for p in problems), problems
