"""A vendor is one folder: outside ``lidarpkt/vendors/`` (and the synthetic fixtures, which are made of
sensors' packets), code asks the vendor registry and names no vendor. Counted here: identifiers and string
literals that are no docstring matching a vendor, product or vendor format name (case-insensitive;
comments and docstrings do not count), read with ``tokenize`` and ``ast``. What remains is held under a
limit: the container format names of frame files, and the spellings a user types."""

from __future__ import annotations

import ast
import io
import re
import tokenize
from pathlib import Path

PACKAGE = Path(__file__).resolve().parents[1] / "lidarpkt"
VENDOR_NAMES = re.compile(r"velodyne|ouster|hesai|vlp|hdl|pandar|osf|robosense|helios", re.IGNORECASE)
EXEMPT = ("vendors", "fixtures")  # the vendor folders; the fixtures generate the vendors' packets
MOST_NAMES, MOST_MODULES = 60, 6


def _docstrings(tree: ast.AST) -> set[tuple[int, int]]:
    """(line, column) of every docstring: the first statement of a module, class or function, a string."""
    out = set()
    for node in ast.walk(tree):
        if isinstance(node, (ast.Module, ast.ClassDef, ast.FunctionDef, ast.AsyncFunctionDef)) and node.body:
            first = node.body[0]
            if isinstance(first, ast.Expr) and isinstance(first.value, ast.Constant) and isinstance(first.value.value, str):
                out.add((first.lineno, first.col_offset))
    return out


def vendor_names(source: str) -> int:
    """Occurrences of a vendor name in the identifiers and non-docstring string literals of ``source``."""
    docs = _docstrings(ast.parse(source))
    count = 0
    for tok in tokenize.generate_tokens(io.StringIO(source).readline):
        if tok.type == tokenize.NAME or (tok.type == tokenize.STRING and tok.start not in docs):
            count += len(VENDOR_NAMES.findall(tok.string))
    return count


def counts() -> dict[str, int]:
    """Vendor names per module outside the exempt folders (modules with none left out)."""
    out = {}
    for path in sorted(PACKAGE.rglob("*.py")):
        rel = path.relative_to(PACKAGE)
        if rel.parts[0] in EXEMPT:
            continue
        n = vendor_names(path.read_text(encoding="utf-8"))
        if n:
            out[f"lidarpkt/{rel.as_posix()}"] = n
    return out


def test_the_counter_counts_names_and_strings_not_docstrings_nor_comments():
    source = ('"""Velodyne."""\n'
              'def f(vlp16_dual):  # Ouster\n'
              '    """An HDL-64E."""\n'
              '    return "ouster/metadata" + f"{vlp16_dual} OSF"\n')
    assert vendor_names(source) == 4  # the parameter twice, the two strings; not the docstrings or the comment


def test_code_outside_the_vendor_folders_names_few_vendors():
    found = counts()
    total = sum(found.values())
    listed = ", ".join(f"{m} {n}" for m, n in sorted(found.items(), key=lambda kv: -kv[1]))
    assert total <= MOST_NAMES and len(found) <= MOST_MODULES, (
        f"{total} vendor names in {len(found)} modules outside lidarpkt/vendors (at most {MOST_NAMES} in "
        f"{MOST_MODULES}): {listed}. Ask the vendor registry (lidarpkt.vendors.registry) instead")
