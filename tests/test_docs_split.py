"""docs/ holds design apart from results: a design page (``docs/NAME.md``) holds no generated
block, its results page (``docs/results/NAME.md``) holds them, every result is argued on its
design page, and every block a page names by name exists (issue 42, item 7)."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

from kilonet.experiments import publish

ROOT = Path(__file__).resolve().parent.parent
DOCS = ROOT / "docs"
#: Results pages made of generated blocks, each beside the design page of the same name.
RESULTS = sorted(p for p in (DOCS / "results").glob("*.md") if publish.blocks_in(p.read_text()))
PAGES = [*DOCS.glob("**/*.md"), ROOT / "README.md", *ROOT.glob("examples/**/*.md")]
#: "block `NAME`", "blocks `A` and `B`", "`A`, `B` and `C` blocks" in prose.
CITED = re.compile(
    r"\bblocks? ((?:`[\w.-]+`(?:, | and )?)+)|((?:`[\w.-]+`(?:, | and )?)+) blocks?\b", re.I
)


def ids(path: Path) -> str:
    return path.relative_to(ROOT).as_posix()


def test_there_are_results_pages():
    assert {p.stem for p in RESULTS} >= {"gcs", "model", "follower"}


@pytest.mark.parametrize("results", RESULTS, ids=ids)
def test_a_design_page_holds_no_generated_block_and_argues_each_of_its_results(results):
    design = (DOCS / results.name).read_text()
    assert publish.blocks_in(design) == [], f"{results.name} still holds generated blocks"
    for name in publish.blocks_in(results.read_text()):
        assert f"`{name}`" in design, f"docs/{results.name} never names its block {name!r}"
    assert f"(../{results.name})" in results.read_text(), "the results page links its design"


def test_every_block_sits_on_exactly_one_page():
    pages: dict[str, list[str]] = {}
    for page in PAGES:
        for name in publish.blocks_in(page.read_text()):
            pages.setdefault(name, []).append(ids(page))
    assert {name: where for name, where in pages.items() if len(where) > 1} == {}


@pytest.mark.parametrize("page", sorted(DOCS.glob("**/*.md")), ids=ids)
def test_every_block_a_page_names_exists(page):
    for match in CITED.finditer(" ".join(page.read_text().split())):
        for name in re.findall(r"`([\w.-]+)`", match.group(0)):
            if name == "NAME":  # the placeholder of `publish docs --block NAME`
                continue
            assert name in publish.BLOCKS, f"{page.name} names a block {name!r} that does not exist"


@pytest.mark.parametrize("page", sorted((DOCS / "results").glob("*.md")), ids=ids)
def test_every_relative_link_of_a_results_page_points_to_a_shipped_file(page):
    for target in re.findall(r"\]\(([^)#\s]+)\)", page.read_text()):
        if "://" not in target:
            assert (page.parent / target).exists(), f"{page.name} links to a missing {target}"


@pytest.mark.parametrize(
    ("repeat", "crlb_robots", "gcs_robots"),
    [pytest.param(5, 1000, None, marks=pytest.mark.slow), (1, 100, 20)],
    ids=["published", "small"],
)
def test_the_math_block_times_every_function_and_counts_the_gcs_runs_calls(
    repeat, crlb_robots, gcs_robots
):
    context = publish.Context(runs=ROOT / "runs", workers=1)
    sizes = {"repeat": repeat, "crlb_robots": crlb_robots, "gcs_robots": gcs_robots}
    lines = publish._math_block(context, **sizes).splitlines()
    robots = "" if gcs_robots is None else f" --robots {gcs_robots}"
    assert lines[0].endswith(f"| calls in `kilonet run gcs --seed 1{robots}` |")
    rows = [line.split("|")[1:-1] for line in lines if line.startswith("| `")]
    names = [cells[0].strip() for cells in rows]
    assert names[:2] == ["`half_map (3 members)`", "`level_matrix`"] and len(names) == 10
    assert all(float(cells[1]) > 0 for cells in rows)
    calls = {name: cells[3].strip() for name, cells in zip(names, rows, strict=True)}
    assert int(calls["`half_map (3 members)`"].replace(",", "")) > 0
    assert lines[-1].startswith("Calls × difference: the hand-written versions save ")
    assert f"`crlb_rmse_mm` on {crlb_robots:,} robots: " in lines[-1]
    assert f"best of {repeat} rounds" in lines[-1]


def test_the_occlusion_block_reads_the_shipped_argos_runs():
    lines = publish._occlusion_block(publish.Context(runs=ROOT / "runs", workers=1)).splitlines()
    rows = [[cell.strip() for cell in line.split("|")[1:-1]] for line in lines[2:] if "|" in line]
    assert [(d, k) for d, k, _, _ in rows] == [
        ("50.0", "0"),
        ("70.7", "0"),
        ("100.0", "1"),
        ("111.8", "0"),
        ("141.4", "1"),
        ("150.0", "2"),
        ("158.1", "2"),
    ]
    assert all(0.0 < float(rate) < 1.0 for _, _, rate, _ in rows)
    assert sum(int(pairs.replace(",", "")) for *_, pairs in rows) <= 50 * 25 * 24
    assert re.fullmatch(
        r"Loss per body of the links at 100 mm, against clear links interpolated to that length: "
        r"[+-]\d+\.\d\d% ± \d+\.\d\d% \(standard error over the 50 runs\)\.",
        lines[-1],
    )
