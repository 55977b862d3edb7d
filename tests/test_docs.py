"""What a reader of the pages relies on: the README's Python examples run as written and its commands parse (a
newcomer copies them first), every relative link leads to a file and heading, every test a page names exists, the
faults table says for each fault what the run does and which test shows it, and the map format page that the
shipped maps' headers point to ships beside them, its example a map the loader reads.
"""

import contextlib
import io
import re
import subprocess
from importlib import resources
from pathlib import Path


from cq_ros.gridmap import available_maps, map_text, parse_map

ROOT = Path(__file__).resolve().parent.parent
README = ROOT / "README.md"

PAGES = sorted((ROOT / "docs").glob("*.md"))


def test_the_readmes_python_examples_run_as_written():
    blocks = re.findall(r"^```python\n(.*?)^```$", README.read_text(), flags=re.S | re.M)
    assert blocks  # the README shows Python examples, so the check sees them
    for block in blocks:
        printed = io.StringIO()
        with contextlib.redirect_stdout(printed):
            exec(compile(block, "README.md", "exec"), {})
        assert printed.getvalue().strip(), f"the example printed nothing:\n{block}"


def test_the_maps_headers_point_to_the_format_page_shipped_beside_them():
    pointing = [name for name in available_maps() if "see README.md in this folder" in map_text(name)]
    assert pointing  # the paper's maps say so in their header
    page = resources.files("cq_ros") / "maps" / "README.md"
    assert page.is_file()
    assert "README" not in available_maps()
    example = re.search(r"^```\n(.*?)^```$", page.read_text(encoding="utf-8"), flags=re.S | re.M)[1]
    gridmap = parse_map(example, source="cq_ros/maps/README.md")
    assert (gridmap.n_agents, gridmap.n_cells, gridmap.defaults) == (2, 25, {"reward_step": -1})


def _anchors(page: Path) -> set[str]:
    """GitHub's anchors of a page's headings: lower case, punctuation dropped, spaces as hyphens."""
    headings = re.findall(r"^#+ (.+)$", page.read_text(encoding="utf-8"), flags=re.M)
    return {re.sub(r"[^\w\- ]", "", h.strip().lower()).replace(" ", "-") for h in headings}


def test_every_relative_link_of_the_readme_and_the_pages_leads_to_a_file_and_heading():
    broken = []
    for page in [README, ROOT / "CHANGELOG.md", ROOT / "cq_ros" / "maps" / "README.md", *PAGES]:
        for target in re.findall(r"\]\(([^)\s]+)\)", page.read_text(encoding="utf-8")):
            path, _, anchor = target.partition("#")
            if "://" in target:
                continue
            linked = (page.parent / path) if path else page
            if not linked.exists() or (anchor and linked.suffix == ".md" and anchor not in _anchors(linked)):
                broken.append(f"{page.relative_to(ROOT)}: {target}")
    assert not broken


# A citation the repository cannot follow: the design brief it was built from, or a tracker's issue number.
OUTSIDE = re.compile(r"DESIGN\.md|\b[Ii]ssues? #?[0-9]+\b|\(#[0-9]+\)")


def test_no_project_file_cites_a_document_or_tracker_outside_the_repository():
    tracked = subprocess.run(["git", "ls-files"], cwd=ROOT, capture_output=True, text=True, check=True,
                             timeout=60).stdout.split()
    here = Path(__file__).relative_to(ROOT).as_posix()
    texts = [name for name in tracked if name != here and (ROOT / name).is_file()
             and Path(name).suffix in (".py", ".md", ".toml", ".txt", ".yaml", ".xml", ".cfg", "")]
    cited = [f"{name}:{n}: {line.strip()}" for name in texts
             for n, line in enumerate((ROOT / name).read_text(errors="replace").splitlines(), 1)
             if OUTSIDE.search(line)]
    assert cited == []
    assert OUTSIDE.search("see issue 18") and OUTSIDE.search("(DESIGN.md, field notes)")


def _defined_tests() -> set[str]:
    return {name for path in (ROOT / "tests").glob("test_*.py")
            for name in re.findall(r"^\s*(?:async )?def (test_\w+)", path.read_text(), re.M)}


def test_every_test_a_page_names_exists():
    """A page that says which test shows something names a test the suite has (renamed or removed, the page
    would point nowhere)."""
    defined = _defined_tests()
    pages = [README, ROOT / "msgs_spec" / "README.md", *(ROOT / "docs").glob("*.md")]
    named = {(page.name, name) for page in pages for name in re.findall(r"`(test_\w+)`", page.read_text())}
    assert named  # the pages name tests, so the check sees them
    assert [f"{page}: {name}" for page, name in sorted(named) if name not in defined] == []


def test_the_faults_table_says_per_fault_what_the_run_does_what_is_counted_and_the_test_that_shows_it():
    rows = [line for line in (ROOT / "docs" / "faults.md").read_text().splitlines() if line.startswith("| ")]
    cells = [[c.strip() for c in re.split(r"(?<!\\)\|", row)[1:-1]] for row in rows]
    assert cells[0] == ["fault", "what the run does", "counted", "shown by"]
    for fault, does, _counted, shown in cells[2:]:
        assert does and re.fullmatch(r"`test_\w+`(, `test_\w+`)*", shown), fault


def _readme_commands() -> list[list[str]]:
    """Each `cq-ros ...` command of the README's shell blocks, its continuation lines joined, with its optional
    parts ([...]) and trailing comments left out."""
    commands = []
    for lang, block in re.findall(r"^```(\w*)\n(.*?)^```$", README.read_text(), flags=re.S | re.M):
        if lang not in ("", "sh", "bash"):
            continue
        for line in block.replace("\\\n", " ").splitlines():
            line = re.sub(r"\s+#.*$", "", line).strip()
            words = re.sub(r"\[[^\]]*\]", "", line).split()
            if words and words[0] in ("cq-ros", ".venv/bin/cq-ros"):
                commands.append(words[1:])
    return commands


def test_the_readmes_commands_parse():
    from cq_ros.cli.main import build_parser

    commands = _readme_commands()
    assert commands  # the README shows cq-ros commands, so the check sees them
    parser = build_parser()
    for argv in commands:
        try:
            parser.parse_args(argv)
        except SystemExit as exc:
            raise AssertionError(f"README: `cq-ros {' '.join(argv)}` does not parse") from exc
