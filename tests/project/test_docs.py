"""The README and docs stay legible: the README and docs/speed.md are short, each generated
table has one home (no results file feeds blocks in two files), every relative link and anchor
resolves, and docs/architecture.md names the import-rules test and only files, functions and
classes that exist."""

from __future__ import annotations

import re
import sys
from pathlib import Path

import mujoco

ROOT = Path(__file__).resolve().parents[2]
DOCS = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]
LINKED = [*DOCS, *(p for p in [ROOT / "CHANGELOG.md"] if p.exists())]

# `<!-- m3p2i report A B -->`, `<!-- m3p2i grid A -->`, `<!-- soak A -->`, `<!-- benchmark A -->`
BLOCK = re.compile(r"^<!-- (?:m3p2i (?:report|grid)|soak|benchmark) (?P<sources>[^>]*?) -->$", re.M)
LINK = re.compile(r"(?<!`)\[[^\]]*\]\((?P<target>[^)\s]+)\)")
FENCE = re.compile(r"^```.*?^```", re.S | re.M)


def _lines(path: Path) -> int:
    return len(path.read_text(encoding="utf-8").splitlines())


def test_the_readme_and_the_speed_page_are_short():
    assert _lines(ROOT / "README.md") <= 150
    assert _lines(ROOT / "docs" / "speed.md") <= 150


def block_sources(text: str) -> list[str]:
    return [s for m in BLOCK.finditer(text) for s in m["sources"].split()]


def test_each_generated_table_has_one_home():
    homes: dict[Path, set[Path]] = {}
    for doc in DOCS:
        for source in block_sources(doc.read_text(encoding="utf-8")):
            path = (doc.parent / source).resolve()
            assert path.is_file(), f"{doc.relative_to(ROOT)}: block source {source} is not a file"
            homes.setdefault(path, set()).add(doc)
    shared = {
        str(p.relative_to(ROOT)): sorted(str(d.relative_to(ROOT)) for d in docs)
        for p, docs in homes.items()
        if len(docs) > 1
    }
    assert not shared, f"results files feeding blocks in more than one file: {shared}"
    assert homes, "no generated block found"


def test_block_sources_are_collected_from_every_kind_of_block():
    text = (
        "<!-- m3p2i report a.csv b.csv -->\n<!-- end of report -->\n<!-- m3p2i grid c.csv -->\n"
        "<!-- soak d.json -->\n<!-- benchmark e.json -->\n`<!-- m3p2i report PATH... -->`\n"
    )
    assert block_sources(text) == ["a.csv", "b.csv", "c.csv", "d.json", "e.json"]


def anchors(path: Path) -> set[str]:
    """GitHub's heading anchors: lower case, punctuation but - and _ dropped, spaces to -."""
    text = FENCE.sub("", path.read_text(encoding="utf-8"))
    out = set()
    for m in re.finditer(r"^#{1,6} (.+)$", text, re.M):
        slug = re.sub(r"[^\w\- ]", "", m[1].strip().lower()).replace(" ", "-")
        out.add(slug)
    return out


def broken_links(doc: Path) -> list[str]:
    text = FENCE.sub("", doc.read_text(encoding="utf-8"))
    text = re.sub(r"`[^`]*`", "", text)
    bad = []
    for m in LINK.finditer(text):
        target = m["target"]
        if re.match(r"[a-z]+:", target):  # http(s), mailto: not checked offline
            continue
        file, _, anchor = target.partition("#")
        path = (doc.parent / file).resolve() if file else doc
        if not path.exists():
            bad.append(f"{target}: no such file")
        elif anchor and path.suffix == ".md" and anchor not in anchors(path):
            bad.append(f"{target}: no heading #{anchor}")
    return bad


def test_every_link_in_the_readme_and_docs_resolves():
    bad = {str(d.relative_to(ROOT)): broken_links(d) for d in LINKED}
    assert not {k: v for k, v in bad.items() if v}, bad


def test_the_architecture_page_names_the_import_rules_test():
    text = (ROOT / "docs" / "architecture.md").read_text(encoding="utf-8")
    assert "tests/project/test_import_rules.py" in text


# ------------------------------------------------------- names in docs/architecture.md exist

CODE_DIRS = ("server", "planner_client", "shared", "m3p2i", "scripts", "tests")
PACKAGES = ("server", "planner_client", "shared", "m3p2i")
SPAN = re.compile(r"`([^`\n]+)`")
FILE_THEN_NAME = re.compile(r"`([\w/]+\.py)` `(\w+)`")
DOTTED = re.compile(r"(?:{})(?:\.\w+)+".format("|".join(PACKAGES)))


def _code_files() -> list[Path]:
    return [p for d in CODE_DIRS for p in (ROOT / d).rglob("*") if "__pycache__" not in p.parts]


def _defines(path: Path, name: str) -> bool:
    return (
        re.search(rf"^\s*(?:def|class)\s+{name}\b", path.read_text(encoding="utf-8"), re.M)
        is not None
    )


def missing_names(text: str) -> list[str]:
    """What a page names in backticks that the code lacks: paths (``mirror.py``,
    ``mppi/sampling.py``, ``scripts/measure/``), a function or class after its file
    (```controller.py` `_plan_start```), dotted names in the packages
    (``server.inprocess.run_episode``) and classes (``Controller``, ``Controller.step``; not
    MuJoCo's, such as ``MjData``)."""
    files = _code_files()
    rel = [p.relative_to(ROOT).as_posix() + ("/" if p.is_dir() else "") for p in files]
    missing = []
    for file, name in FILE_THEN_NAME.findall(text):
        hits = [p for p, r in zip(files, rel) if r.endswith(file) and p.is_file()]
        if not any(_defines(p, name) for p in hits):
            missing.append(f"{file} {name}")
    for span in set(SPAN.findall(text)):
        if re.fullmatch(r"[\w./-]+(\.py|/)", span):
            if not (ROOT / span).exists() and not any(r.endswith("/" + span) for r in rel):
                missing.append(span)
        elif DOTTED.fullmatch(span):
            parts = span.split(".")
            for cut in range(len(parts), 0, -1):
                module = ROOT.joinpath(*parts[:cut])
                source = (
                    module.with_suffix(".py")
                    if module.with_suffix(".py").is_file()
                    else (module / "__init__.py")
                )
                if source.is_file():
                    rest = parts[cut:]
                    if rest and not _defines(source, rest[0]):
                        missing.append(span)
                    break
            else:
                missing.append(span)
        elif re.fullmatch(r"[A-Z][a-z]\w*(?:\.\w+)?", span) and not hasattr(mujoco, span):
            cls, _, method = span.partition(".")
            owners = [p for p in files if p.suffix == ".py" and _defines(p, cls)]
            if not owners or (method and not any(_defines(p, method) for p in owners)):
                missing.append(span)
    return sorted(missing)


def test_the_architecture_page_names_only_files_and_functions_that_exist():
    text = (ROOT / "docs" / "architecture.md").read_text(encoding="utf-8")
    assert missing_names(text) == []


def test_a_stale_name_on_the_architecture_page_is_found():
    stale = (
        "`loop.py` `_plan_start`, `controller.py` `_plan_start`, `mirror.py`, `gone.py`, "
        "`mppi/sampling.py`, `mppi/nothing.py`, `server.inprocess.run_episode`, "
        "`server.inprocess.walk_episode`, `Controller.step`, `Controller.fly`, `Nobody`"
    )
    assert missing_names(stale) == sorted(
        [
            "loop.py _plan_start",
            "gone.py",
            "mppi/nothing.py",
            "server.inprocess.walk_episode",
            "Controller.fly",
            "Nobody",
        ]
    )


# ------------------------------------------- docs/scenarios.md and the scenario schema agree

SCENARIO_READERS = ("shared.scenario", "shared.scenario.guide", "shared.predicates")
# mappings keyed by the user's names: objectives.NAME, planner.model.geoms.NAME, ...
NAMED = re.compile(r"^(objectives|planner\.model\.geoms|planner\.model\.objects)\.[^.\[]+")
FENCED_KEY = re.compile(r"^\s*-?\s*([A-Za-z_]\w*):", re.M)
ANY_FENCE = re.compile(r"^[ \t]*```.*?^[ \t]*```", re.S | re.M)  # indented in lists too
TABLE_KEYS = re.compile(r"^\| (`[^|]+`) \|", re.M)


def asked_keys() -> set[str]:
    """Every key path the scenario readers ask for while loading the shipped scenarios
    (``world.objects[].size``; a user's names as NAME: ``objectives.NAME.terms[].weight``), the
    task's own names (``observers.FACTOR``, ``plan.ACTION``: the template's, documented with it)
    left out."""
    from shared import config
    from shared.scenario import SCENARIO_DIR, load_scenario

    asked: set[str] = set()
    originals = {m: getattr(config.Section, m) for m in ("opt", "req", "section", "items", "has")}

    def recording(original):
        def ask(self, key, *args, **kwargs):
            frame = sys._getframe(1)  # the reader that asked, past ErrorLog.call
            while frame.f_back is not None and frame.f_globals["__name__"] == "shared.config":
                frame = frame.f_back
            caller = frame.f_globals.get("__name__", "")
            if caller.startswith(SCENARIO_READERS) and isinstance(key, str):
                path = NAMED.sub(r"\1.NAME", re.sub(r"\[\d+\]", "[]", self.key_path(key)))
                if not path.startswith(("observers.", "plan.")):
                    asked.add(path)
            return original(self, key, *args, **kwargs)

        return ask

    try:
        for name, original in originals.items():
            setattr(config.Section, name, recording(original))
        for path in sorted(SCENARIO_DIR.glob("*.yaml")):
            load_scenario(path)
    finally:
        for name, original in originals.items():
            setattr(config.Section, name, original)
    return asked


def documented_names(text: str) -> set[str]:
    """The names a page documents: every word in backticks, and every key of its YAML
    examples."""
    names = {w for span in SPAN.findall(text) for w in re.findall(r"[A-Za-z_]\w*", span)}
    for block in ANY_FENCE.findall(text):
        names |= set(FENCED_KEY.findall(block))
    return names


def undocumented(asked: set[str], text: str) -> list[str]:
    """The asked key paths whose last name ``text`` never mentions."""
    names = documented_names(text) | {"NAME"}
    # a team's robots are named by the scenario, as its objectives are: robots.NAME
    asked = {re.sub(r"^robots\.\w+", "robots.NAME", p) for p in asked}
    return sorted(p for p in asked if re.split(r"[.\[\]]+", p.strip(".[]"))[-1] not in names)


def unknown_table_keys(asked: set[str], text: str) -> list[str]:
    """The key paths of the page's key table (``| `world.objects[]` | ...``) that no reader
    asks for (neither the path nor a key under it)."""
    found = []
    for cell in TABLE_KEYS.findall(text):
        for path in SPAN.findall(cell):
            if "." not in path and "[" not in path and path in {p.split(".")[0] for p in asked}:
                continue
            if not any(p == path or p.startswith((path + ".", path + "[")) for p in asked):
                found.append(path)
    return found


def test_every_scenario_key_is_documented_and_the_key_table_names_only_real_keys():
    asked = asked_keys()
    assert len(asked) > 200  # the readers were recorded
    text = (ROOT / "docs" / "scenarios.md").read_text(encoding="utf-8")
    assert undocumented(asked, text) == []
    table = text.split("## Keys", 1)[-1] if "## Keys" in text else text
    assert unknown_table_keys(asked, table.split("\n## ", 1)[0]) == []


def test_a_key_the_docs_miss_or_invent_is_found():
    asked = {"world.objects[].size", "planner.mppi.gamma", "robot.safe_ctrl"}
    text = "`size` and\n```yaml\nrobot:\n  safe_ctrl: [0]\n```\n| `world.objects[]` | x |\n"
    assert undocumented(asked, text) == ["planner.mppi.gamma"]
    assert unknown_table_keys(asked, text + "| `world.shapes[]` | y |\n") == ["world.shapes[]"]
