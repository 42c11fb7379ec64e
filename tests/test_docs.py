"""The documentation checked against the code (cheap: no FMU is built, nothing is run).

- every relative link in README.md and docs/*.md resolves: the file exists and, for a
  ``#anchor``, the target has that heading (GitHub's anchors);
- every ``flexfusion SUBCOMMAND`` (and ``flexfusion study KIND``) the docs show is one the
  command line's parser (orchestration/cli.py) accepts, and every ``--option`` shown with it is
  one that sub-command's parser knows;
- docs/scenarios.md names, in the right section, every key the scenario loader
  (orchestration/scenario.py) accepts, and documents no key it refuses.

A plain check rather than a docs build tool: the docs are Markdown read on the forge or in a
checkout; what a strict MkDocs/Sphinx build would add over these checks (a site, its
navigation) is not shipped yet."""
from __future__ import annotations

import argparse
import ast
import functools
import re
from pathlib import Path

import pytest

from orchestration import cli

ROOT = Path(__file__).resolve().parent.parent
DOCS = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]
FENCE = re.compile(r"^(```|~~~).*?^\1[ \t]*$", re.M | re.S)
INLINE = re.compile(r"(`+)(.+?)\1", re.S)
LINK = re.compile(r"!?\[(?:[^\]\[]|\[[^\]]*\])*\]\(([^)\s]+)(?:\s+\"[^\"]*\")?\)")


def rel(path: Path) -> str:
    return str(path.relative_to(ROOT))


def prose(text: str) -> str:
    """``text`` without its fenced code blocks and inline code (links there are not links)."""
    return INLINE.sub("", FENCE.sub("", text))


def code(text: str) -> list[str]:
    """The code of ``text``: each fenced block (``\\``-continued lines joined) and inline span."""
    blocks = [re.sub(r"\\\n\s*", " ", m.group(0)) for m in FENCE.finditer(text)]
    return blocks + [m.group(2) for m in INLINE.finditer(FENCE.sub("", text))]


def slug(heading: str) -> str:
    """GitHub's anchor of a heading: markup dropped, lower case, punctuation other than ``-``
    and ``_`` removed, each space a ``-``."""
    text = re.sub(r"\[([^\]]*)\]\([^)]*\)", r"\1", heading)        # a link: its text
    text = text.replace("`", "").strip().lower()
    text = re.sub(r"[^\w\- ]", "", text)
    return text.replace(" ", "-")


def anchors(path: Path) -> set[str]:
    """Every heading anchor of a Markdown file (repeats get ``-1``, ``-2``, ...)."""
    seen: dict[str, int] = {}
    out = set()
    for m in re.finditer(r"^#{1,6}\s+(.+?)\s*#*\s*$", FENCE.sub("", path.read_text()), re.M):
        s = slug(m.group(1))
        n = seen.get(s, 0)
        seen[s] = n + 1
        out.add(s if n == 0 else f"{s}-{n}")
    return out


def test_slug_matches_github() -> None:
    """GitHub's rule on the kinds of heading the docs have: code marks and punctuation dropped,
    each space a ``-`` (so ``: `--set` `` gives three)."""
    assert slug("Overrides: `--set` and Python") == "overrides---set-and-python"
    assert slug("`[[metrics]]`") == "metrics"
    assert slug("What the simulation knows and the estimators don't") == \
        "what-the-simulation-knows-and-the-estimators-dont"
    assert slug("Quick start (2 minutes)") == "quick-start-2-minutes"


def test_docs_exist() -> None:
    names = {p.name for p in DOCS}
    for name in ("README.md", "index.md", "user_guide.md", "scenarios.md", "your_estimator.md",
                 "fmi_hosts.md", "figures.md"):
        assert name in names, f"{name} is missing"


def test_index_lists_every_doc() -> None:
    index = (ROOT / "docs" / "index.md").read_text()
    targets = {m.group(1).split("#")[0] for m in LINK.finditer(prose(index))}
    missing = [p.name for p in DOCS if p.parent == ROOT / "docs" and p.name != "index.md"
               and p.name not in targets]
    assert not missing, f"docs/index.md does not link {missing}"


@pytest.mark.parametrize("doc", DOCS, ids=rel)
def test_relative_links_resolve(doc: Path) -> None:
    bad = []
    for m in LINK.finditer(prose(doc.read_text())):
        target = m.group(1)
        if re.match(r"[a-z][a-z0-9+.-]*:", target):              # http:, https:, mailto:
            continue
        file, _, anchor = target.partition("#")
        path = (doc.parent / file).resolve() if file else doc
        if not path.exists():
            bad.append(f"{target}: no such file")
        elif anchor and path.suffix == ".md" and anchor not in anchors(path):
            bad.append(f"{target}: no heading #{anchor} in {rel(path)}")
        elif anchor and path.suffix != ".md":
            bad.append(f"{target}: an anchor into a file that is not Markdown")
    assert not bad, f"{rel(doc)}: broken links:\n" + "\n".join(bad)


# ---------------------------------------------------------------------------------------------
# the commands shown
# ---------------------------------------------------------------------------------------------
COMMAND = re.compile(r"(?<![\w.$-])(?:[\w.~/-]*/)?flexfusion[ \t]+([a-z][a-z0-9-]*)(?:[ \t]+([a-z][a-z0-9-]*))?"
                     r"([^\n;#|]*(?:\\\|[^\n;#|]*)*)")


def shown_commands() -> list[tuple[str, str, str, str]]:
    """``(doc, subcommand, study kind or "", the rest of the line)`` of every command shown."""
    out = []
    for doc in DOCS:
        for snippet in code(doc.read_text()):
            for m in COMMAND.finditer(snippet):
                sub, second, rest = m.group(1), m.group(2) or "", m.group(3)
                kind = second if sub == "study" else ""
                out.append((rel(doc), sub, kind, rest if kind or not second else f"{second}{rest}"))
    return out


class _Parser(Exception):
    pass


@pytest.fixture(scope="module")
def parser() -> argparse.ArgumentParser:
    """The parser ``flexfusion`` builds, with the study kinds registered (``main`` registers
    them only for a ``study`` command line), caught as it is about to parse."""
    caught = {}
    original = argparse.ArgumentParser.parse_known_args

    def catch(self: argparse.ArgumentParser, *args: object, **kwargs: object) -> None:
        caught["parser"] = self
        raise _Parser

    argparse.ArgumentParser.parse_known_args = catch      # type: ignore[method-assign]
    try:
        with pytest.raises(_Parser):
            cli.main(["study"])
    finally:
        argparse.ArgumentParser.parse_known_args = original  # type: ignore[method-assign]
    return caught["parser"]


def help_text(parser: argparse.ArgumentParser, argv: list[str], capsys: pytest.CaptureFixture
              ) -> str | None:
    """The help of the sub-command ``argv``, or None if the parser refuses it (argparse's own
    check of a sub-command's name: ``invalid choice``)."""
    try:
        parser.parse_known_args([*argv, "--help"])
    except SystemExit as exc:
        out = capsys.readouterr().out
        return out if exc.code == 0 else None
    return ""                    # a sub-command without its own --help (build: its own parser)


def test_shown_commands_are_real(parser: argparse.ArgumentParser,
                                 capsys: pytest.CaptureFixture) -> None:
    commands = shown_commands()
    assert len(commands) > 40, "the command pattern found too few commands: is it broken?"
    kinds = {k for _, s, k, _ in commands if s == "study"}
    assert {"montecarlo", "sweep", "tune"} <= kinds
    helps: dict[tuple[str, str], str | None] = {}
    bad = []
    for doc, sub, kind, rest in commands:
        argv = [sub, kind] if kind else [sub]
        if (sub, kind) not in helps:
            helps[sub, kind] = help_text(parser, argv, capsys)
        text = helps[sub, kind]
        if text is None or (sub == "study" and not kind):
            bad.append(f"{doc}: flexfusion {' '.join(argv)}: not a sub-command")
            continue
        if sub == "build":
            from orchestration import build
            text = build.__doc__ or ""
            try:
                build.main(["--help"])
            except SystemExit:
                text = capsys.readouterr().out
        for option in re.findall(r"(?<![\w-])--[a-z][a-z0-9-]*", rest):
            if not re.search(rf"(?<![\w-]){re.escape(option)}(?![\w-])", text):
                bad.append(f"{doc}: flexfusion {' '.join(argv)}: unknown option {option}")
    assert not bad, "\n".join(sorted(set(bad)))


# ---------------------------------------------------------------------------------------------
# the scenario reference
# ---------------------------------------------------------------------------------------------
#: where each table the loader checks is documented: (function, a text its `where` argument
#: holds, or "" for any) -> the heading of its section in docs/scenarios.md
SECTIONS = {
    ("_document", "[scenario]"): "`[scenario]`",
    ("_document", ""): "Top level",
    ("merge_include", ""): "`[scenario]`",            # an include file's keys: its paragraph
    ("_components", ""): "`[components.NAME]`",
    ("_record", ""): "`[record]`",
    ("_metric", ""): "`[[metrics]]`",
}


@functools.cache
def loader_keys() -> dict[str, set[str]]:
    """The keys ``orchestration/scenario.py`` accepts, per section of the reference: the sets
    every ``_check_keys(where, table, ALLOWED)`` call is given (a set literal or a module
    constant), read from the source."""
    tree = ast.parse((ROOT / "orchestration" / "scenario.py").read_text())
    constants = {t.id: node.value for node in tree.body if isinstance(node, ast.Assign)
                 for t in node.targets if isinstance(t, ast.Name)}
    out: dict[str, set[str]] = {}
    for func in ast.walk(tree):
        if not isinstance(func, ast.FunctionDef):
            continue
        for call in ast.walk(func):
            if not (isinstance(call, ast.Call) and isinstance(call.func, ast.Name)
                    and call.func.id == "_check_keys"):
                continue
            allowed = call.args[2]
            if isinstance(allowed, ast.Name):
                allowed = constants[allowed.id]
            keys = ast.literal_eval(allowed)
            where = ast.unparse(call.args[0])
            section = next((s for (f, w), s in SECTIONS.items() if f == func.name and w in where), None)
            assert section, (f"orchestration/scenario.py: {func.name} checks the keys {sorted(keys)} "
                             f"of a table ({where}) that tests/test_docs.py does not know: document "
                             "it in docs/scenarios.md and add it to SECTIONS")
            out.setdefault(section, set()).update(keys)
    return out


def sections(path: Path) -> dict[str, str]:
    text = path.read_text()
    parts = re.split(r"^## (.+)$", text, flags=re.M)
    return {parts[i].strip(): parts[i + 1] for i in range(1, len(parts), 2)}


def test_scenario_reference_names_every_key() -> None:
    keys = loader_keys()
    assert set(keys) == set(SECTIONS.values())
    assert len(set().union(*keys.values())) >= 25, "too few keys read from the loader"
    doc = sections(ROOT / "docs" / "scenarios.md")
    missing = [f"{section}: `{k}`" for section, ks in keys.items() for k in sorted(ks)
               if section not in doc or f"`{k}`" not in doc[section]]
    assert not missing, "docs/scenarios.md does not name these keys the loader accepts:\n" + \
        "\n".join(missing)


def test_scenario_reference_documents_no_other_key() -> None:
    """The first column of each section's ``| key |`` table holds only keys the loader accepts."""
    keys = loader_keys()
    doc = sections(ROOT / "docs" / "scenarios.md")
    bad = []
    for section, ks in keys.items():
        rows = re.findall(r"^\| (.+?) \|", doc.get(section, ""), re.M)
        if not rows or rows[0] != "key":
            continue
        documented = {k for row in rows[2:] for k in re.findall(r"`([^`]+)`", row)}
        bad += [f"{section}: `{k}`" for k in sorted(documented - ks)]
    assert not bad, "docs/scenarios.md documents keys the loader refuses:\n" + "\n".join(bad)
