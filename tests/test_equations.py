"""The equation index (docs/EQUATIONS.md) names real code and real tests, and no equation reference is bare.

Three checks:

1. Every row of the table in ``docs/EQUATIONS.md`` either names its home, one or
   more `` `module:name` `` (or `` `module.name` ``) that import (the module
   imports, the name is an attribute of it), and its tests, one or more
   `` `tests/file.py::test_name` `` whose file defines that test function; or
   says **not yet built** and names no test.

2. Every equation or algorithm reference in ``spikejax/`` and ``robots/`` names
   its paper. The rule, precisely:

   - A *reference* is a match of `REFERENCE` ("Eq. (9)", "Eqs. (4)-(6)",
     "Eq. 7", "Equation (2)", "Alg. 1", "Algorithm 3") inside a string literal
     (docstrings included) or a comment.
   - A *paper name* is a match of one of `PAPERS` ("RoboBee paper", "hexapod
     SCPG paper", "pipe-tracking paper" or "pipe paper", "snake R-STDP paper", a line break
     allowed between the words; "paper's" counts, "papers" does not).
   - A *block* is one string literal, a run of comment lines on consecutive
     lines (lines holding nothing but the comment), or a comment after code on
     its line.
     A *sentence* is a stretch of a block between sentence ends: ``.``, ``!`` or
     ``?`` followed by white space (the dots of the abbreviations in
     `ABBREVIATIONS` do not end sentences), a blank line, or the start of a
     list item (a line starting with ``-``, ``*`` or ``1.``).
   - A reference is unambiguous if its sentence names a paper, or else if the
     papers named in its block and in its module's docstring are, together,
     exactly one paper.

   So a module whose docstring names exactly one paper may write bare "Eq. (9)"
   in its own docstrings, unless a docstring (or comment run) names another
   paper too; a module that names none or several must name the paper in the
   sentence of each reference, or in a block that alone names one paper.

3. Every equation or algorithm the code cites, attributed to one paper by that
   rule, has a row of that paper in the index whose "Equation" cell covers its
   number ("Eq. (4)-(6)" covers 4, 5 and 6).
"""

from __future__ import annotations

import ast
import importlib
import io
import re
import tokenize
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
INDEX = ROOT / "docs" / "EQUATIONS.md"
SOURCES = ("spikejax", "robots")

PAPERS = {
    "RoboBee": re.compile(r"\bRoboBee\s+paper\b"),
    "hexapod SCPG": re.compile(r"\bhexapod\s+(?:SCPG\s+)?paper\b"),
    "pipe-tracking": re.compile(r"\bpipe(?:-tracking)?\s+paper\b"),
    "snake R-STDP": re.compile(r"\bR-STDP\s+paper\b"),
}
REFERENCE = re.compile(
    r"\b(?:(?P<eq>Eqs?\.|Equations?)\s*(?P<eqs>\(?\d+\)?(?:\s*(?:-|,|and)\s*\(?\d+\)?)*)"
    r"|(?P<alg>Alg(?:s?\.|orithms?))\s*(?P<algs>\d+(?:\s*(?:-|,|and)\s*\d+)*))"
)
ABBREVIATIONS = (
    "Eqs.",
    "Eq.",
    "Algs.",
    "Alg.",
    "Secs.",
    "Sec.",
    "Figs.",
    "Fig.",
    "e.g.",
    "i.e.",
    "et al.",
    "cf.",
    "vs.",
    "ref.",
    "Ref.",
    "resp.",
    "approx.",
)
_SENTENCE_END = re.compile(r"[.!?](?=\s)|\n\s*\n|\n(?=\s*(?:[-*]|\d+[.)])\s)")
_HOME = re.compile(r"`([A-Za-z_][\w.]*(?::[\w.]+)?)`")
_TEST = re.compile(r"`(tests/[\w/]+\.py)::(\w+)`")


# ------------------------------------------------------------------ the index


def _rows() -> list[tuple[int, list[str]]]:
    """The table's body rows as (line number, cells)."""
    rows = []
    for number, line in enumerate(INDEX.read_text().splitlines(), 1):
        if not line.startswith("|"):
            continue
        cells = [cell.strip() for cell in line.strip().strip("|").split("|")]
        if cells[0] == "Paper" or set("".join(cells)) <= set("-: "):
            continue  # the header and the rule under it
        rows.append((number, cells))
    return rows


def _resolve(name: str):
    """The object that ``module:attr`` or ``module.attr`` names (raises if there is none)."""
    if ":" in name:
        module_name, attrs = name.split(":", 1)
        target = importlib.import_module(module_name)
    else:
        parts = name.split(".")
        for cut in range(len(parts) - 1, 0, -1):
            try:
                target = importlib.import_module(".".join(parts[:cut]))
            except ModuleNotFoundError:
                continue
            attrs = ".".join(parts[cut:])
            break
        else:
            raise ModuleNotFoundError(f"no module in {name!r}")
    for attr in attrs.split("."):
        target = getattr(target, attr)
    return target


def _test_functions(path: Path) -> set[str]:
    tree = ast.parse(path.read_text())
    return {node.name for node in ast.walk(tree) if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef))}


def test_index_has_a_row_per_paper():
    papers = {cells[0] for _, cells in _rows()}
    assert papers == {"RoboBee", "hexapod SCPG", "pipe-tracking", "snake R-STDP"}


def test_every_home_imports_and_every_test_exists():
    problems = []
    for number, cells in _rows():
        if len(cells) != 5:
            problems.append(f"EQUATIONS.md:{number}: {len(cells)} cells, want 5 (paper, equation, what, home, test)")
            continue
        paper, equation, _, home, tests = cells
        where = f"EQUATIONS.md:{number} ({paper} {equation})"
        if "not yet built" in home:
            if tests:
                problems.append(f"{where}: not yet built, yet names a test")
            continue
        homes, named = _HOME.findall(home), _TEST.findall(tests)
        if not homes:
            problems.append(f"{where}: no home")
        if not named:
            problems.append(f"{where}: no test")
        for name in homes:
            try:
                _resolve(name)
            except (ImportError, AttributeError) as err:
                problems.append(f"{where}: {name}: {type(err).__name__}: {err}")
        for file, function in named:
            path = ROOT / file
            if not path.is_file():
                problems.append(f"{where}: no file {file}")
            elif function not in _test_functions(path):
                problems.append(f"{where}: {file} defines no {function}")
    assert not problems, "\n".join(problems)


def test_resolve_names_both_spellings():
    from spikejax.coding import decoder_step

    assert _resolve("spikejax.coding:decoder_step") is decoder_step
    assert _resolve("spikejax.coding.decoder_step") is decoder_step
    with pytest.raises(AttributeError):
        _resolve("spikejax.coding:no_such_function")


# ------------------------------------------------------------- bare references


def _papers(text: str) -> set[str]:
    return {paper for paper, pattern in PAPERS.items() if pattern.search(text)}


def _blocks(source: str) -> tuple[str, list[tuple[int, str]]]:
    """The module docstring, and every block as (first line number, text)."""
    tree = ast.parse(source)
    lines = source.splitlines(keepends=True)
    blocks = []
    for node in ast.walk(tree):
        if isinstance(node, ast.JoinedStr):  # its source text (ast.get_source_segment splits the file on every call)
            span = lines[node.lineno - 1 : node.end_lineno]
            span[-1] = span[-1].encode()[: node.end_col_offset].decode()
            span[0] = span[0].encode()[node.col_offset :].decode()
            blocks.append((node.lineno, "".join(span)))
        elif isinstance(node, ast.Constant) and isinstance(node.value, str):
            blocks.append((node.lineno, node.value))
    run: list[str] = []
    start = last = -2
    for token in tokenize.generate_tokens(io.StringIO(source).readline):
        if token.type != tokenize.COMMENT:
            continue
        line = token.start[0]
        if not token.line.strip().startswith("#"):  # after code: a block of its own
            blocks.append((line, token.string.lstrip("#").strip()))
            continue
        if line != last + 1 and run:
            blocks.append((start, "\n".join(run)))
            run = []
        if not run:
            start = line
        run.append(token.string.lstrip("#").strip())
        last = line
    if run:
        blocks.append((start, "\n".join(run)))
    return ast.get_docstring(tree) or "", blocks


def _mask(text: str) -> str:
    """``text`` with the dots of abbreviations replaced (same length, so offsets hold)."""
    for abbreviation in ABBREVIATIONS:
        text = re.sub(rf"(?<![\w.]){re.escape(abbreviation)}", abbreviation.replace(".", "\x00"), text)
    return text


def _sentence(text: str, masked: str, offset: int) -> str:
    starts = [m.end() for m in _SENTENCE_END.finditer(masked) if m.end() <= offset]
    ends = [m.start() for m in _SENTENCE_END.finditer(masked) if m.start() >= offset]
    return text[(starts[-1] if starts else 0) : (ends[0] + 1 if ends else len(text))]


def _numbers(match: re.Match) -> set[tuple[str, int]]:
    """``{("Eq", 4), ("Eq", 5), ("Eq", 6)}`` for "Eqs. (4)-(6)", ``{("Alg", 1)}`` for "Alg. 1"."""
    kind, spec = ("Eq", match["eqs"]) if match["eq"] else ("Alg", match["algs"])
    found = set()
    for part in re.split(r"\s*(?:,|and)\s*", spec):
        bounds = [int(n) for n in re.findall(r"\d+", part)]
        found.update((kind, n) for n in range(bounds[0], bounds[-1] + 1))
    return found


def references(source: str) -> list[tuple[int, str, str | None, set[tuple[str, int]]]]:
    """Every reference of ``source`` as (line, sentence, paper, numbers).

    ``paper`` is the paper the rule of this module's docstring gives it: the one
    its sentence names, or else the one its block and module name together;
    ``None`` when that is not exactly one paper (when the sentence names several,
    the reference is unambiguous to a reader but not attributed here).
    """
    docstring, blocks = _blocks(source)
    module_papers = _papers(docstring)
    found = []
    for first_line, text in blocks:
        block_papers = _papers(text)
        masked = _mask(text)
        for match in REFERENCE.finditer(text):
            sentence = _sentence(text, masked, match.start())
            papers = _papers(sentence) or block_papers | module_papers
            line = first_line + text.count("\n", 0, match.start())
            paper = next(iter(papers)) if len(papers) == 1 else None
            found.append((line, " ".join(sentence.split()), paper, _numbers(match)))
    return found


def bare_references(source: str) -> list[tuple[int, str]]:
    """The references of ``source`` that the rule of this module's docstring calls ambiguous, as (line, sentence)."""
    found = []
    for line, sentence, paper, _ in references(source):
        if paper is None and not _papers(sentence):
            found.append((line, sentence))
    return found


def _sources():
    for package in SOURCES:
        yield from sorted((ROOT / package).rglob("*.py"))


def test_the_rule_by_hand():
    one = '"""Decoders, Eq. (8) of the RoboBee paper."""\n\ndef f():\n    """Eq. (8) again: bare is fine here."""\n'
    assert bare_references(one) == []
    other = one + '\ndef g():\n    """Eq. (9). Unlike the snake R-STDP paper, '
    other += 'which uses Eq. (3) of the pipe-tracking paper."""\n'
    assert [line for line, _ in bare_references(other)] == [7]
    none = '"""No paper here."""\n# Eq. (2) of the pipe-tracking paper, and\n'
    none += "# Eq. (3): one comment block, one paper.\nx = 1  # Alg. 1\n"
    assert [line for line, _ in bare_references(none)] == [4]
    two = '"""Gait and camera.\n\nSee Eq. (5), e.g. Sec. 2.4 and Fig. 3 of the pipe-tracking paper. Then Eq. 6.\n\n'
    two += '- Eq. (1) of the snake R-STDP\n  paper.\n- Eq. (12)\n"""\n'
    assert [sentence for _, sentence in bare_references(two)] == ["Then Eq. 6.", "- Eq. (12)"]


def test_reference_numbers():
    source = '"""Eqs. (4)-(6) and Eq. (1), (9) of the pipe-tracking paper; Alg. 3, line 11 of the RoboBee paper."""'
    got = {(paper, frozenset(numbers)) for _, _, paper, numbers in references(source)}
    assert got == {
        (None, frozenset({("Eq", 4), ("Eq", 5), ("Eq", 6)})),
        (None, frozenset({("Eq", 1), ("Eq", 9)})),
        (None, frozenset({("Alg", 3)})),
    }
    source = '"""Eq. 7 of the snake R-STDP paper, then Algorithm 2."""'
    assert [(paper, numbers) for _, _, paper, numbers in references(source)] == [
        ("snake R-STDP", {("Eq", 7)}),
        ("snake R-STDP", {("Alg", 2)}),
    ]


def test_every_equation_reference_names_its_paper():
    problems = []
    for path in _sources():
        for line, sentence in bare_references(path.read_text()):
            problems.append(f"{path.relative_to(ROOT)}:{line}: {sentence[:150]}")
    assert not problems, "references that do not name their paper:\n" + "\n".join(problems)


def test_every_equation_the_code_cites_has_a_row():
    """Each equation or algorithm a docstring or comment cites, with its paper, is in docs/EQUATIONS.md."""
    indexed = set()
    for _, cells in _rows():
        for match in REFERENCE.finditer(cells[1]):
            indexed.update((cells[0], kind, n) for kind, n in _numbers(match))
    problems = []
    for path in _sources():
        for line, sentence, paper, numbers in references(path.read_text()):
            for kind, n in sorted(numbers):
                if paper is not None and (paper, kind, n) not in indexed:
                    where = f"{path.relative_to(ROOT)}:{line}"
                    problems.append(f"{where}: {kind}. {n} of the {paper} paper: {sentence[:100]}")
    assert not problems, "cited but not in docs/EQUATIONS.md:\n" + "\n".join(problems)
