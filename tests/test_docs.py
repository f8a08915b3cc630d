"""The docs agree with the code and with themselves.

- docs/cli.md names every option of every command's parser (built from
  calib_oed.cli), in that command's own section.
- Figures quoted in several places are read from their one source and checked
  wherever they are quoted: the study's figures (docs/study.md, Tables 6-8 and
  its result paragraphs, copied from the study reports) in its summary table
  and in README.md's Status; the link-geometry acceptance (docs/feasibility.md,
  the table of bench/bench_feasibility_mesh.py) in docs/scenes.md and
  docs/feasibility.md; the design pipeline's efficiencies and times
  (docs/benchmarks.md) in its summaries and docs/oed.md.
- docs/benchmarks.md's commands exist with the options they are given.
- DEVELOPERS.md's module map lists every module; links between the docs resolve.
- Test files (and tests) that modules, docs, README.md, DEVELOPERS.md, benchmarks,
  examples and shipped YAML comments name are there.
- docs/uncertainty.md's noise-model table quotes the quick starts (README.md, docs/quickstart.md).
"""

from __future__ import annotations

import argparse
import functools
import math
import re
from pathlib import Path

import pytest

from calib_oed.cli import build_parser

ROOT = Path(__file__).parent.parent
DOCS = ROOT / "docs"


def read(name: str) -> str:
    return (ROOT / name).read_text(encoding="utf-8")


# --------------------------------------------------------------------------- CLI options


@functools.cache
def subcommands() -> dict[str, argparse.ArgumentParser]:
    parser = build_parser()
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            return dict(action.choices)
    raise AssertionError("calib_oed.cli.build_parser has no subcommands")


def section(text: str, heading: str) -> str | None:
    """The text under a markdown heading line, up to the next heading of that level or above."""
    match = re.search(rf"^(#+) {re.escape(heading)}\s*$", text, flags=re.M)
    if match is None:
        return None
    level = len(match.group(1))
    rest = text[match.end():]
    stop = re.search(rf"^#{{1,{level}}} ", rest, flags=re.M)
    return rest[: stop.start()] if stop else rest


def names_option(text: str, option: str) -> bool:
    """`option` appears as a whole word (so -n does not match -N or --no-refine)."""
    return re.search(rf"(?<![\w-]){re.escape(option)}(?![\w-])", text) is not None


def option_strings(parser: argparse.ArgumentParser) -> list[str]:
    return [o for action in parser._actions for o in action.option_strings if o not in ("-h", "--help")]


def test_cli_md_has_a_section_per_command():
    text = read("docs/cli.md")
    missing = [name for name in subcommands() if section(text, f"`{name}`") is None]
    assert not missing, ("docs/cli.md lacks a section '### `COMMAND`' for: "
                         + ", ".join(missing))


@pytest.mark.parametrize("command", sorted(subcommands()))
def test_cli_md_names_every_option(command):
    """Every option `calib-oed COMMAND -h` shows is in COMMAND's section of docs/cli.md."""
    body = section(read("docs/cli.md"), f"`{command}`")
    assert body is not None, f"docs/cli.md has no section '### `{command}`'"
    missing = [o for o in option_strings(subcommands()[command]) if not names_option(body, o)]
    assert not missing, (f"docs/cli.md, section `{command}`: option(s) {', '.join(missing)} of "
                         f"`calib-oed {command} -h` not documented")


def test_cli_md_names_the_top_level_options():
    text = read("docs/cli.md")
    missing = [o for o in option_strings(build_parser()) if not names_option(text, o)]
    assert not missing, f"docs/cli.md: top-level option(s) {', '.join(missing)} not documented"


# --------------------------------------------------------------------------- tables


def table_after(text: str, caption: str) -> list[list[str]]:
    """The rows (cells stripped) of the first markdown table after the line starting with
    `caption`, header included, separator left out."""
    start = text.find(caption)
    assert start >= 0, f"caption {caption!r} not found"
    rows, seen = [], False
    lines = text[start:].splitlines()
    for line in lines if lines[0].startswith("|") else lines[1:]:
        if line.startswith("|"):
            seen = True
            cells = [c.strip() for c in line.strip().strip("|").split("|")]
            if not all(re.fullmatch(r":?-+:?", c) for c in cells):
                rows.append(cells)
        elif seen:
            break
    assert rows, f"no table after {caption!r}"
    return rows


def number(cell: str) -> float:
    match = re.search(r"-?\d+(?:\.\d+)?(?:e-?\d+)?", cell.replace("**", ""))
    assert match, f"no number in table cell {cell!r}"
    return float(match.group())


def percent_range(low: float, high: float, digits: int) -> str:
    return f"{low:.{digits}f}–{high:.{digits}f} %"


# --------------------------------------------------------------------------- the study's figures


def whole_percent(value: float) -> int:
    """A percentage to whole percent, halves up (88.5 % -> 89 %)."""
    return math.floor(value + 0.5)


def whole_range(low: float, high: float) -> str:
    return f"{whole_percent(low)}–{whole_percent(high)} %"


class Study:
    """docs/study.md's Tables 6-8 and result paragraphs (copied from the study reports) and what
    follows from them."""

    def __init__(self):
        self.text = text = read("docs/study.md")
        table6 = table_after(text, "Table 6 analogue")
        col = {name: i for i, name in enumerate(table6[0])}
        self.kuka = {row[0]: {
            "heuristic": number(row[col["heuristic (median) [mm²]"]]),
            "params": number(row[col["C_p-optimal [mm²]"]]),
            "kpi": number(row[col["KPI-optimal [mm²]"]]),
            "vs_heuristic": number(row[col["KPI-opt vs heuristic"]]),
            "vs_params": number(row[col["KPI-opt vs C_p-opt"]]),
            "bound": number(row[col["lower bound [mm²]"]]),
            "efficiency": number(row[col["KPI-opt efficiency"]]),
        } for row in table6[1:]}
        table7 = {row[0]: row for row in table_after(text, "Table 7 analogue")}
        self.arms_vs_heuristic = (number(table7["min"][4]), number(table7["max"][4]))
        self.arms_vs_params = (number(table7["min"][5]), number(table7["max"][5]))
        table8 = {row[0]: row for row in table_after(text, "Table 8 analogue")}
        self.arms_mean_vs_heuristic = number(table8["KPI-opt vs heuristic (mean of arms)"][1])
        self.arms_mean_vs_params = number(table8["KPI-opt vs C_p-opt (mean of arms)"][1])
        self.arms_kpi_with = number(table8["KPI-optimal [mm²]"][1])
        self.arms_kpi_without = number(table8["KPI-optimal [mm²]"][2])
        flat = " ".join(text.split())
        sqrt = re.search(r"In the standard deviation √V .*? design is (\d+\.\d–\d+\.\d %) \(mean (\d+\.\d) %\) "
                         r"better than the heuristic median and (\d+\.\d–\d+\.\d %) \(mean (\d+\.\d) %\)", flat)
        assert sqrt, "docs/study.md: the 90 arms' paragraph on the standard deviation √V not found"
        self.arms_sqrt = {"heuristic": (sqrt.group(1), sqrt.group(2)), "params": (sqrt.group(3), sqrt.group(4))}
        collide = re.findall(r"Colliding poses of the designs optimised without collision constraints: "
                             r"C_p-optimal (\d+–\d+ %) \(mean (\d+) %\), KPI-optimal (\d+–\d+ %) \(mean (\d+) %\)", flat)
        assert len(collide) == 2, "docs/study.md: expected the colliding-poses sentence of both studies"
        self.kuka_collide, self.arms_collide = collide
        converged = re.search(r"of the 360 SQP designs (\d+) converged", flat)
        assert converged, "docs/study.md: the 90 arms' solver paragraph not found"
        self.arms_converged = int(converged.group(1))

    def kuka_range(self, key: str) -> tuple[float, float]:
        values = [arm[key] for arm in self.kuka.values()]
        return min(values), max(values)

    def kuka_mean(self, key: str) -> float:
        return sum(arm[key] for arm in self.kuka.values()) / len(self.kuka)

    def kuka_sqrt(self, other: str) -> list[float]:
        """Per arm, the improvement in the standard deviation √V [%], from the variances."""
        return [100 * (1 - math.sqrt(arm["kpi"] / arm[other])) for arm in self.kuka.values()]


@pytest.fixture(scope="module")
def study() -> Study:
    return Study()


def test_table6_follows_from_its_variances(study):
    for name, arm in study.kuka.items():
        assert arm["vs_heuristic"] == pytest.approx(100 * (1 - arm["kpi"] / arm["heuristic"]), abs=0.15), name
        assert arm["vs_params"] == pytest.approx(100 * (1 - arm["kpi"] / arm["params"]), abs=0.15), name
        assert arm["efficiency"] == pytest.approx(100 * arm["bound"] / arm["kpi"], abs=0.15), name


def test_study_text_on_table6_quotes_it(study):
    flat = " ".join(study.text.split())
    gap = [100 - arm["efficiency"] for arm in study.kuka.values()]
    assert f"within {whole_range(min(gap), max(gap)).replace(' %', '')} % of the best" in flat
    best = [100 * (1 - arm["bound"] / arm["heuristic"]) for arm in study.kuka.values()]
    assert f"by more than {whole_range(min(best), max(best))}" in flat


def summary_row(text: str, claim: str) -> list[str]:
    rows = {row[0]: row for row in table_after(text, "## Our numbers next to the paper's")}
    assert claim in rows, f"docs/study.md's summary table has no row {claim!r}"
    return rows[claim]


def test_study_summary_table_quotes_the_study_tables(study):
    text = study.text
    row = summary_row(text, "KPI-optimal vs heuristic, in the variance V")
    low, high = study.kuka_range("vs_heuristic")
    assert row[2] == f"{percent_range(low, high, 1)} (mean {study.kuka_mean('vs_heuristic'):.1f} %)"
    low, high = study.arms_vs_heuristic
    assert row[3] == f"{percent_range(low, high, 1)} (mean {study.arms_mean_vs_heuristic:.1f} %)"

    row = summary_row(text, "KPI-optimal vs C_p-optimal, in V")
    low, high = study.kuka_range("vs_params")
    assert row[2] == f"{percent_range(low, high, 1)} (mean {study.kuka_mean('vs_params'):.1f} %)"
    low, high = study.arms_vs_params
    assert row[3] == f"{percent_range(low, high, 1)} (mean {study.arms_mean_vs_params:.1f} %)"

    for claim, other, (low, high) in (
            ("the same in the standard deviation √V", "heuristic", study.arms_vs_heuristic),
            ("the same in √V", "params", study.arms_vs_params)):
        values = study.kuka_sqrt(other)
        row = summary_row(text, claim)
        assert row[2] == f"{percent_range(min(values), max(values), 1)} (mean {sum(values) / len(values):.1f} %)"
        quoted, mean = study.arms_sqrt[other]
        assert row[3] == f"{quoted} (mean {mean} %)", claim
        # the 90 arms' extremes in √V are Table 7's per-arm extremes in V, mapped (a monotone map)
        for value, extreme in zip(map(float, re.findall(r"\d+\.\d", quoted)), (low, high), strict=False):
            bounds = [100 * (1 - math.sqrt(1 - (extreme + d) / 100)) for d in (-0.05, 0.05)]
            assert bounds[0] - 0.05 <= value <= bounds[1] + 0.05, (
                f"docs/study.md: {quoted} in √V does not follow from Table 7's {low}–{high} %")

    for claim, index in (("colliding poses without collision constraints, C_p-optimal", 0),
                         ("the same, KPI-optimal", 2)):
        row = summary_row(text, claim)
        assert row[2] == f"{study.kuka_collide[index]} (mean {study.kuka_collide[index + 1]} %)", claim
        assert row[3] == f"{study.arms_collide[index]} (mean {study.arms_collide[index + 1]} %)", claim

    cost = 100 * (math.sqrt(study.arms_kpi_with / study.arms_kpi_without) - 1)
    row = summary_row(text, "cost of collision avoidance for the KPI-optimal design (Table 8, in √V)")
    assert row[3] == (f"{cost:.1f} % (√({study.arms_kpi_with * 1e6:.3f}/"
                      f"{study.arms_kpi_without * 1e6:.3f}) − 1)")


def test_study_discussion_quotes_the_study(study):
    flat = " ".join(study.text.split())
    assert f"collide in {study.arms_collide[0]} of their poses" in flat
    assert f"({study.arms_converged} of 360 SQP runs to the KKT" in flat
    heuristic, params = study.arms_sqrt["heuristic"][0], study.arms_sqrt["params"][0]
    assert f"√V, \"the precision\" of its abstract ({heuristic} over the 90 arms)" in flat
    whole_params = [whole_percent(float(x)) for x in re.findall(r"\d+\.\d", params)]
    assert f"far more than 10–19 % ({whole_params[0]}–{whole_params[1]} % in √V)" in flat



def test_study_text_on_the_colliding_design_quotes_table6(study):
    """The design below the certified bound is the no-collision table's, the bound Table 6's."""
    flat = " ".join(study.text.split())
    found = re.search(r"The (\w+) KPI-optimal design without collision constraints \((\S+) mm²\) "
                      r"is \*below\* the certified bound for feasible designs \((\S+) mm²\)", flat)
    assert found, "docs/study.md: the sentence on the design below the certified bound not found"
    arm, value, bound = found.group(1), float(found.group(2)), float(found.group(3))
    without = {row[0]: row for row in table_after(study.text, "Without collision avoidance (the designs")}
    assert value == number(without[arm][3]) and bound == study.kuka[arm]["bound"] and value < bound


def test_study_solver_counts_add_up(study):
    """The 90 arms' solver paragraph: its converged designs per (criterion, collisions) sum to the
    total it states, and the C_p-optimal design's share of the heuristic's V is Table 8's."""
    flat = " ".join(study.text.split())
    paragraph = re.search(r"Solver \(of the 360 SQP designs \d+ converged\):(.*?)\. Every design", flat)
    assert paragraph, "docs/study.md: the 90 arms' solver paragraph not found"
    counts = [int(c) for c in re.findall(r"(\d+) (?:× `)?converged", paragraph.group(1))]
    assert len(counts) == 4 and sum(counts) == study.arms_converged
    table8 = {row[0]: row for row in table_after(study.text, "Table 8 analogue")}
    params, heuristic = number(table8["C_p-optimal [mm²]"][1]), number(table8["heuristic (median) [mm²]"][1])
    assert (f"KPI variance at {whole_percent(100 * params / heuristic)} % of the heuristic's "
            f"(Table 8: {params:.4g} against {heuristic:.4g} mm²)") in flat


def test_monte_carlo_check_is_of_table6s_designs(study):
    """The Monte Carlo table's predicted tr C_s are 3 V of Table 6's kr16 designs (so a rerun of
    the study without one of the Monte Carlo check shows), and its percentages follow from it."""
    rows = {row[0].split(" (")[0]: row for row in table_after(study.text, "| design (kr16, with collision avoidance)")}
    for name, key in (("C_p-optimal", "params"), ("KPI-optimal", "kpi")):
        assert number(rows[name][3]) == pytest.approx(3 * study.kuka["kr16"][key], rel=5e-4), name
    flat = " ".join(study.text.split())
    kpi = rows["KPI-optimal"]
    for other, name in (("heuristic", "the heuristic design's"), ("C_p-optimal", "the C_p-optimal design's")):
        empirical = 100 * (1 - number(kpi[2]) / number(rows[other][2]))
        predicted = 100 * (1 - number(kpi[3]) / number(rows[other][3]))
        assert re.search(rf"\*\*{empirical:.1f} %\*\* below {name} \(predicted {predicted:.1f} %", flat), other


def pages() -> list[str]:
    return ["README.md", "DEVELOPERS.md", *sorted(f"docs/{p.name}" for p in DOCS.glob("*.md"))]


@pytest.mark.parametrize("name", pages())
def test_quoted_study_figures_match_the_tables(study, name):
    """Where a page gives both studies' improvement, or the KUKA arms' efficiency, in whole
    percent, they are those of docs/study.md's tables."""
    kuka, arms = study.kuka_range("vs_heuristic"), study.arms_vs_heuristic
    vs_heuristic = whole_range(min(kuka[0], arms[0]), max(kuka[1], arms[1]))
    kuka, arms = study.kuka_range("vs_params"), study.arms_vs_params
    vs_params = whole_range(min(kuka[0], arms[0]), max(kuka[1], arms[1]))
    efficiency = whole_range(*study.kuka_range("efficiency"))
    text = " ".join(read(name).split())
    quoted = re.findall(r"by (\d+–\d+ %) against heuristic designs and by (\d+–\d+ %) against "
                        r"the C_p-optimal design", text)
    reach = re.findall(r"KPI-optimal designs reach (\d+–\d+ %) efficiency", text)
    arms = re.search(r"arms\): KPI-optimal \*\*(\d+\.\d)–(\d+\.\d) %\*\*", " ".join(study.text.split()))
    assert arms, "docs/study.md: the 90 arms' efficiency sentence not found"
    arms_efficiency = whole_range(float(arms.group(1)), float(arms.group(2)))
    on_arms = re.findall(r"efficiency on the three KUKA arms \([^)]*\) and (\d+–\d+ %) on the 90 notional arms", text)
    if name == "README.md":
        assert quoted and reach, "README.md's Status should quote the study's figures"
    for found in quoted:
        assert found == (vs_heuristic, vs_params), (
            f"{name} quotes {found[0]} / {found[1]}; docs/study.md's tables give {vs_heuristic} / {vs_params}")
    for found in reach:
        assert found == efficiency, f"{name} quotes {found}; docs/study.md's Table 6 gives {efficiency}"
    for found in on_arms:
        assert found == arms_efficiency, f"{name} quotes {found}; docs/study.md gives {arms_efficiency} on the 90 arms"
    if name == "README.md":
        assert on_arms, "README.md's Status should quote the 90 arms' efficiency"


# --------------------------------------------------------------------------- acceptance of the link geometry


def acceptance() -> dict[str, tuple[float, float]]:
    """Per link model, the lowest and highest share of mesh-feasible configurations accepted
    over the cells of docs/feasibility.md's table (bench/bench_feasibility_mesh.py)."""
    rows = table_after(read("docs/feasibility.md"), "| Cell | mesh-feasible |")
    header, body = rows[0], rows[1:]
    columns = {"single": next(i for i, h in enumerate(header) if "one capsule per link" in h),
               "split": next(i for i, h in enumerate(header) if "`split`" in h and "accepted" in h),
               "hulls": next(i for i, h in enumerate(header) if "`hulls`" in h and "accepted," in h)}
    return {model: (min(number(r[i]) for r in body), max(number(r[i]) for r in body))
            for model, i in columns.items()}


def whole(extremes: tuple[float, float]) -> str:
    return whole_range(*extremes)


def test_acceptance_quotes_match_the_table():
    accepted = acceptance()
    scenes = " ".join(read("docs/scenes.md").split())
    assert f"{whole(accepted['hulls'])} of the mesh-feasible poses accepted" in scenes
    assert f"one capsule per link fitted to the URDF collision geometry: {whole(accepted['single'])} " \
           "accepted" in scenes, (
        f"docs/scenes.md should quote the single-capsule acceptance {whole(accepted['single'])} "
        "of docs/feasibility.md's table")
    feasibility = " ".join(read("docs/feasibility.md").split())
    capsules = (min(accepted["single"][0], accepted["split"][0]), max(accepted["single"][1], accepted["split"][1]))
    for phrase in ("cells accepted against", "With capsules alone the acceptance stays at"):
        found = re.findall(rf"{phrase} (\d+–\d+ %)", feasibility)
        assert found, f"docs/feasibility.md: phrase {phrase!r} not found"
        assert found == [whole(capsules)] * len(found), (
            f"docs/feasibility.md: {phrase} {found}, the table gives {whole(capsules)}")


# --------------------------------------------------------------------------- benchmark commands


def benchmark_commands() -> list[str]:
    """The commands of docs/benchmarks.md: its indented code lines and its `...` spans that
    run a bench script or calib-oed."""
    text = read("docs/benchmarks.md")
    lines = [line.strip() for line in text.splitlines() if line.startswith("    ") and line.strip()]
    lines += re.findall(r"`([^`\n]*(?:bench/\w+\.py|calib-oed \w)[^`\n]*)`", text)
    return [line.split("  #")[0].strip() for line in lines
            if re.search(r"bench/\w+\.py|calib-oed \w", line) and not line.startswith("#")]


def test_benchmark_scripts_take_the_options_the_docs_give():
    commands = benchmark_commands()
    assert commands, "docs/benchmarks.md: no command found"
    for command in commands:
        for script in re.findall(r"bench/\w+\.py", command):
            path = ROOT / script
            assert path.is_file(), f"docs/benchmarks.md runs {script}, which does not exist"
            source = path.read_text(encoding="utf-8")
            tail = command.split(script, 1)[1]
            for flag in re.findall(r"(?<![\w-])(--[a-z][\w-]*)", tail):
                assert f'"{flag}"' in source, f"docs/benchmarks.md: {script} has no option {flag} (`{command}`)"


def test_benchmark_calib_oed_commands_parse():
    """Every calib-oed command docs/benchmarks.md gives is accepted by today's parser."""
    parser = build_parser()
    checked = 0
    for command in benchmark_commands():
        match = re.search(r"calib-oed (\w.*)", command)
        if match is None or "[" in match.group(1) or "bench/" in match.group(1) or " " not in match.group(1):
            continue  # optional parts, a bench script's arguments, or a command named in prose
        argv = match.group(1).split()
        try:
            parser.parse_args(argv)
        except SystemExit:
            pytest.fail(f"docs/benchmarks.md: `calib-oed {match.group(1)}` is not a valid command today")
        known = set(option_strings(subcommands()[argv[0]]))
        for token in argv[1:]:  # whole names: argparse would accept an abbreviation
            flag = token.split("=")[0]
            if re.fullmatch(r"--?[a-zA-Z][\w-]*", flag):
                assert flag in known, f"docs/benchmarks.md: `calib-oed {argv[0]}` has no option {flag}"
        checked += 1
    assert checked, "docs/benchmarks.md: no calib-oed command checked"


# --------------------------------------------------------------------------- the module map


def test_developers_module_map_lists_every_module():
    """DEVELOPERS.md's module map has a line for every module of calib_oed, under its package."""
    text = section(read("DEVELOPERS.md"), "Module map")
    assert text is not None, "DEVELOPERS.md has no '## Module map'"
    blocks = dict(re.findall(r"^\*\*(\w+/|Base modules)\*\*(.*?)(?=^\*\*|\Z)", text, flags=re.M | re.S))
    package = ROOT / "calib_oed"
    missing = []
    for path in sorted(package.rglob("*.py")):
        rel = path.relative_to(package)
        if "shipped" in rel.parts or rel.name == "__main__.py" or rel == Path("__init__.py"):
            continue
        if rel.name == "__init__.py" and rel.parent.name != "cli":
            continue  # a package's __init__ re-exports its names (said once, above the map)
        key = "Base modules" if len(rel.parts) == 1 else f"{rel.parts[0]}/"
        if f"`{rel.name}`" not in blocks.get(key, ""):
            missing.append(str(rel))
    assert not missing, "DEVELOPERS.md's module map lacks: " + ", ".join(missing)


# --------------------------------------------------------------------------- links between the docs


def heading_anchors(path: Path) -> set[str]:
    """GitHub's anchors of a markdown file's headings (lower case, punctuation dropped,
    spaces as hyphens)."""
    anchors = set()
    in_code = False
    for line in path.read_text(encoding="utf-8").splitlines():
        if line.startswith("```"):
            in_code = not in_code
        match = None if in_code else re.match(r"#+ (.*)", line)
        if match:
            anchors.add(re.sub(r"[^\w\- ]", "", match.group(1).strip().lower()).replace(" ", "-"))
    return anchors


def test_links_between_the_docs_resolve():
    pages_ = [ROOT / "README.md", ROOT / "DEVELOPERS.md", ROOT / "examples" / "README.md",
              *sorted(DOCS.glob("*.md"))]
    broken = []
    for page in pages_:
        for target, anchor in re.findall(r"\]\(([^)#\s:]*\.md)?(?:#([^)\s]+))?\)", page.read_text(encoding="utf-8")):
            if not target and not anchor:
                continue
            path = (page.parent / target) if target else page
            if not path.is_file():
                broken.append(f"{page.relative_to(ROOT)}: {target}")
            elif anchor and anchor not in heading_anchors(path):
                broken.append(f"{page.relative_to(ROOT)}: {target}#{anchor}")
    assert not broken, "links to missing pages or headings: " + "; ".join(broken)


def _texts_naming_tests() -> list[Path]:
    """Every text that may say where something is checked: the package's modules and shipped
    YAML (its comments), the docs, README.md, DEVELOPERS.md, the benchmarks and examples."""
    return sorted([*(ROOT / "calib_oed").rglob("*.py"), *(ROOT / "calib_oed").rglob("shipped/*.yaml"),
                   *DOCS.glob("*.md"), ROOT / "README.md", ROOT / "DEVELOPERS.md",
                   *(ROOT / "bench").rglob("*.py"), *(ROOT / "examples").rglob("*.py")])


def test_test_files_named_in_the_texts_exist():
    """A module, doc page or shipped YAML that says where it is checked (``tests/.../test_x.py``,
    or ``tests/.../test_x.py::test_name``) names a file, and a test in it, that is there."""
    texts = _texts_naming_tests()
    assert any(p.suffix == ".yaml" for p in texts) and DOCS / "oed.md" in texts
    missing = set()
    for path in texts:
        for name, test in re.findall(r"(tests/[\w/]+\.py)(?:::(\w+))?", path.read_text(encoding="utf-8")):
            target = ROOT / name
            if not target.is_file() or (test and not re.search(rf"^\s*def {test}\(", target.read_text(
                    encoding="utf-8"), re.MULTILINE)):
                missing.add(f"{path.relative_to(ROOT)}: {name}{'::' + test if test else ''}")
    assert not missing, "test files or tests named but missing: " + "; ".join(sorted(missing))


# --------------------------------------------------------------------------- design figures quoted from benchmarks.md


def test_design_figures_quoted_from_the_benchmark_tables():
    """docs/oed.md and the benchmarks' own summaries quote the pipeline and default-call tables."""
    bench = read("docs/benchmarks.md")
    rows = table_after(bench, "    OPENBLAS_NUM_THREADS=1 .venv/bin/python bench/bench_design_pipeline.py --scenes all --replicates 1,3")
    col = {name: i for i, name in enumerate(rows[0])}
    efficiency = {k: [number(r[col["efficiency"]]) for r in rows[1:] if r[col["K"]] == k] for k in ("1", "3")}
    k1 = f"{min(efficiency['1']):.1f}–{max(efficiency['1']):.1f} %"
    k3 = f"{min(efficiency['3']):.1f}–{max(efficiency['3']):.1f} %"
    calls = table_after(bench, "    OPENBLAS_NUM_THREADS=1 /usr/bin/time .venv/bin/calib-oed design fms_kr16 -n 60 --criterion kpi -o DIR")
    col = {name: i for i, name in enumerate(calls[0])}
    today, then = calls[1], calls[2]  # what it prints today; the timed runs on the machine of 2026-11-24
    assert today[col["measured"]].startswith("2026-11-26") and then[col["measured"]].startswith("2026-11-24")
    cpu = then[col["CPU user + sys [s]"]]

    flat_bench = " ".join(bench.split())
    assert f"efficiency {k1} with K = 1, {k3} with K = 3" in flat_bench
    assert f"On the machine of 2026-11-24, {cpu} s: the target was met" in flat_bench
    oed = " ".join(read("docs/oed.md").split())
    assert f"at {k1} of the bound (`--replicates 3`: {k3})" in oed
    assert (f"ends at {today[col['KPI avg var [mm²]']]} mm² of KPI average variance, "
            f"**{today[col['efficiency']]}** of the certified bound, in {today[col['SQP iterations']]} SQP "
            f"iterations (2026-11-26); alone on the machine of 2026-11-24 the whole process took {cpu} s of CPU") in oed


# --------------------------------------------------------------------------- the feasibility command's report


@functools.cache
def feasibility_of(scene: str):
    """``(FeasibilityModel, PairReport)`` of a shipped scene (built once per session)."""
    from calib_oed.feasibility.pairs import feasibility_from_scene
    from calib_oed.scene.reader import load_scene

    return feasibility_from_scene(load_scene(scene))


def test_feasibility_md_shows_the_pairs_and_rows_fms_kr16_has_today():
    """docs/feasibility.md's `calib-oed feasibility fms_kr16 -n 60` output: its pair report (the lines
    before the design's) is the one the scene gives today, and the text's pair counts by kind add up."""
    text = read("docs/feasibility.md")
    block = text.split("$ .venv/bin/calib-oed feasibility fms_kr16 -n 60\n", 1)[1].split("\n\ndesign:", 1)[0]
    model, report = feasibility_of("fms_kr16")
    assert block.splitlines()[1:] == report.summary().splitlines()
    kinds = [label.split(":", 1)[0] for label in report.checked]
    flat = " ".join(text.split())
    rows = model.count_per_pose()
    assert (f"The {len(kinds)} checked pairs are {kinds.count('self')} self, {kinds.count('obstacle')} "
            f"obstacle and {kinds.count('beam')} beam pairs") in flat
    assert f"they are {rows['self']} + {rows['obstacle']} + {rows['beam']} rows" in flat


def test_concepts_quotes_the_monte_carlo_of_identification_md():
    """docs/concepts.md's Monte Carlo figures are those of docs/identification.md's table."""
    rows = table_after(read("docs/identification.md"), "| quantity (car_side, 1000 runs) | value |")
    value = {r[0]: r[1] for r in rows[1:]}
    before = value["TCP RMS error before calibration (3-D)"]
    after = value["TCP RMS error after calibration (3-D)"]
    ratio = value["ratio mean ‖e‖² / tr $C_s$"].split(" (")[0]
    coverage = value["coverage of the 95 % ellipsoid"]
    concepts = " ".join(read("docs/concepts.md").split())
    assert (f"TCP RMS error {before} before and {after} after calibration, ratio {ratio}, "
            f"coverage {coverage}") in concepts


def test_feasibility_md_rows_per_pose_of_the_shipped_scenes():
    """docs/feasibility.md's rows per pose with the default link geometry, scene by scene."""
    flat = " ".join(read("docs/feasibility.md").split())
    quoted = []
    for scene in ("fms_kr16", "fms_kr16_program", "fms_kr300", "fms_kr500", "ur5_table"):
        model, _ = feasibility_of(scene)
        rows = model.count_per_pose()
        quoted.append((sum(rows.values()), rows["self"], len(model.hull_pairs.labels)))
    (kr16, program, kr300, kr500, ur5) = quoted
    assert kr16 == program
    assert (f"`fms_kr16` and `fms_kr16_program` {kr16[0]} rows per pose (self {kr16[1]}, {kr16[2]} of them "
            "on convex pieces") in flat
    for name, (total, self_rows, pieces) in (("fms_kr300", kr300), ("fms_kr500", kr500), ("ur5_table", ur5)):
        assert f"`{name}` {total} (self {self_rows}, {pieces} on pieces" in flat, name


def test_uncertainty_md_quotes_the_quick_starts():
    """docs/uncertainty.md's table of what the shipped noise model changes quotes, in its shipped
    column, the heuristic σ and the validation's noise floor of docs/quickstart.md and the
    KPI-optimal share of README.md's quick start (both checked against a run by test_quickstart);
    the isotropic noise floor is √3 × the scene's 0.01 mm."""
    rows = {r[0]: r for r in table_after(read("docs/uncertainty.md"), "| fms_kr16, 60 poses |")}
    quick = " ".join(read("docs/quickstart.md").split())
    heuristic = re.search(r"the heuristic design \(([\d.e-]+) mm², ([\d.]+) mm\)", quick)
    floor = re.search(r"noise floor \(a perfect model\): RMS ([\d.]+) mm", quick)
    share = re.search(r"KPI-optimal: (\d+)% of the heuristic's variance", read("README.md"))
    assert heuristic and floor and share, "quick starts: the quoted lines were not found"
    assert math.sqrt(float(heuristic.group(1))) == pytest.approx(float(heuristic.group(2)), abs=5e-6)
    assert rows["heuristic KPI σ per axis"][2] == f"{1e3 * float(heuristic.group(2)):.2f} µm"
    assert rows["validation noise floor (30 poses)"][2] == f"{floor.group(1)} mm"
    assert rows["validation noise floor (30 poses)"][1] == f"{math.sqrt(3) * 0.01:.4f} mm"
    assert f"({share.group(1)} % of the heuristic's variance" in rows["KPI-optimal KPI σ per axis"][2]
