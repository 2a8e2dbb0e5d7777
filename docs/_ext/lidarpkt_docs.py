"""The site's own Sphinx glue: the CLI parser for sphinx-argparse, and cross-references resolved by identity.

The docstrings name things where they are defined (``lidarpkt.pipeline.reader.open_frames``,
``lidarpkt.core.frame.Frame``, ``OutputError`` inside a module that imports it); the API reference
documents them under their public names (``lidarpkt.open``, ``lidarpkt.Frame``,
``lidarpkt.errors.OutputError``). A reference Sphinx cannot resolve by name is imported and linked
to the documented name of the same object. What is left:

- a ``lidarpkt`` name that does not exist (a misspelt or removed name): a warning, so the build fails;
- an existing but undocumented internal (``lidarpkt.core.kernels``) or another library's name
  (``numpy.ndarray``): shown as code, without a link (the site reaches no other site's inventory).
"""

from __future__ import annotations

import argparse
import importlib
import inspect
import re
import sys
from typing import Any

from docutils import nodes
from docutils.parsers.rst import directives
from docutils.statemachine import StringList
from sphinx.application import Sphinx
from sphinx.util import logging
from sphinx.util.docutils import SphinxDirective
from sphinx.util.nodes import make_refnode, nested_parse_with_titles

logger = logging.getLogger(__name__)
_MISSING = object()


def _rst_text(text: str | None) -> str | None:
    """Help text as reStructuredText that shows it as ``--help`` does (sphinx-argparse parses help as
    reST: ``'*.pcap'`` would open an emphasis, ``|x|`` a substitution, ``name_`` a link)."""
    if not text:
        return text
    text = text.replace("\\", "\\\\").replace("*", "\\*").replace("|", "\\|")
    return re.sub(r"(?<=\w)_(?=\W|$)", r"\\_", text)


def _escape_help(parser: argparse.ArgumentParser) -> argparse.ArgumentParser:
    parser.description = _rst_text(parser.description)
    parser.epilog = _rst_text(parser.epilog)
    for action in parser._actions:
        if action.help is not argparse.SUPPRESS:
            action.help = _rst_text(action.help)
        if isinstance(action, argparse._SubParsersAction):
            for choice in action._choices_actions:
                choice.help = _rst_text(choice.help)
            for sub in set(action.choices.values()):
                _escape_help(sub)
    return parser


def cli_parser() -> argparse.ArgumentParser:
    """Every verb's parser filled in: what ``reference/cli.md`` documents (sphinx-argparse calls this).
    Only the help texts are changed, escaped for reST."""
    from lidarpkt.cli import build_parser

    return _escape_help(build_parser("*"))


def import_name(path: str) -> Any:
    """The object at dotted ``path``, or ``_MISSING``: attributes first, a submodule imported only where
    its package has no attribute of that name (so that ``lidarpkt.fixtures.canned``, a function, is not
    shadowed by importing the package-data folder ``canned/`` as a namespace package)."""
    parts = path.split(".")
    try:
        obj: Any = importlib.import_module(parts[0])
    except Exception:  # noqa: BLE001 - a module that fails to import is not a target
        return _MISSING
    for i, attr in enumerate(parts[1:], start=2):
        value = getattr(obj, attr, _MISSING)
        if value is _MISSING and inspect.ismodule(obj):
            try:
                value = importlib.import_module(".".join(parts[:i]))
            except Exception:  # noqa: BLE001
                value = _MISSING
        if value is _MISSING:
            return _through_loaded_module(parts)
        obj = value
    return obj


def _through_loaded_module(parts: list[str]) -> Any:
    """``a.b.c.D`` through the loaded module ``a.b.c`` where the package's attribute ``c`` is something
    else (``lidarpkt.archive.export``: the function, and the module that defines it)."""
    for i in range(len(parts) - 1, 1, -1):
        module = sys.modules.get(".".join(parts[:i]))
        if module is None:
            continue
        obj: Any = module
        for attr in parts[i:]:
            obj = getattr(obj, attr, _MISSING)
            if obj is _MISSING:
                return _MISSING
        return obj
    return _MISSING


def _linkable(obj: Any) -> bool:
    # identity means something only for modules, classes and functions (not for 0.1 or "points")
    return inspect.ismodule(obj) or inspect.isclass(obj) or callable(obj)


def _documented(env) -> dict[int, tuple[str, Any]]:
    """id(object) -> (documented name, its domain entry), built once per build."""
    cache = getattr(env, "_lidarpkt_documented", None)
    if cache is None:
        cache = {}
        for name, entry in env.get_domain("py").objects.items():
            if getattr(entry, "aliased", False):
                continue
            obj = import_name(name)
            if obj is not _MISSING and _linkable(obj):
                cache.setdefault(id(obj), (name, entry))
        env._lidarpkt_documented = cache
    return cache


def _origin_module(node) -> str | None:
    """The module that defines the object whose docstring holds ``node`` (autodoc names it in the
    node's source: ``.../frame.py:docstring of lidarpkt.core.frame.Frame.points``), if any."""
    source = None
    while node is not None and not source:
        source = getattr(node, "source", None)
        node = getattr(node, "parent", None)
    match = re.search(r"docstring of ([\w.]+)", source or "")
    if not match:
        return None
    parts = match.group(1).split(".")
    for i in range(len(parts), 0, -1):
        obj = import_name(".".join(parts[:i]))
        if obj is _MISSING:
            continue
        if inspect.ismodule(obj):
            return obj.__name__
        module = getattr(obj, "__module__", None)
        if isinstance(module, str):
            return module
    return None


def _candidates(node) -> list[str]:
    """Where ``node``'s target may be, most specific first: the documented class and module, the module
    that defines the docstring and its packages, then under ``lidarpkt`` and as written."""
    target = node["reftarget"].lstrip("~")
    module, cls = node.get("py:module"), node.get("py:class")
    if target.startswith("."):
        return [f"{module}{target}"] if module else []
    names = []
    if module and cls:
        names.append(f"{module}.{cls}.{target}")
    if module:
        names.append(f"{module}.{target}")
    origin = _origin_module(node)
    while origin:
        names.append(f"{origin}.{target}")
        origin = origin.rpartition(".")[0]
    names += [f"lidarpkt.{target}", target]
    return names


def missing_reference(app: Sphinx, env, node, contnode):
    if node.get("refdomain") != "py":
        return None
    documented = _documented(env)
    for name in _candidates(node):
        obj = import_name(name)
        if obj is _MISSING:
            continue
        if _linkable(obj) and id(obj) in documented:
            public, entry = documented[id(obj)]
            return make_refnode(app.builder, node["refdoc"], entry.docname, entry.node_id, contnode, public)
        return contnode  # real, but internal or another library's: code without a link
    if node["reftarget"].lstrip("~").startswith("lidarpkt."):
        return None  # a lidarpkt name that does not exist: nitpicky warns, -W fails the build
    # another library's name (numpy.ndarray, dict[str, Any]), or words napoleon read as a type
    return contnode


class FormatsDirective(SphinxDirective):
    """``lidarpkt-formats``: a section per output format of ``lidarpkt.writers.FORMATS``, with its writer
    class documented by autodoc, so that a format added to the table is on the site without an edit."""

    def run(self) -> list[nodes.Node]:
        from lidarpkt.writers import FORMATS

        lines: list[str] = []
        documented: set[str] = set()
        for fmt in FORMATS.values():
            module, cls = fmt.writer.split(":")
            target = f"lidarpkt.writers.{module}.{cls}"
            title = f"``{fmt.name}``"
            lines += [title, "~" * len(title), "",
                      f"Suffixes {', '.join(f'``{s}``' for s in fmt.suffixes)}; "
                      f"the output is {'a folder' if fmt.directory else 'a file'}"
                      + (f"; needs {', '.join(f'``{r}``' for r in fmt.requires)} (the ``export`` extra)."
                         if fmt.requires else "."), ""]
            if target in documented:
                lines += [f"Written by :class:`{target}`, as above.", ""]
                continue
            documented.add(target)
            lines += [f".. autoclass:: {target}", "   :members: write, close", "   :no-show-inheritance:", ""]
        container = nodes.container()
        nested_parse_with_titles(self.state, StringList(lines, source="lidarpkt.writers.FORMATS"), container)
        return container.children


class AllNamesDirective(SphinxDirective):
    """``lidarpkt-all MODULE``: an entry for every name of the module's ``__all__`` (but ``:skip:``),
    for packages whose names are imported on first use (a module ``__getattr__``) or from their
    submodules, which ``automodule`` does not list. Classes and functions by autodoc; data with the
    ``#:`` comment of the module that defines it."""

    required_arguments = 1
    option_spec = {"skip": directives.unchanged}

    def run(self) -> list[nodes.Node]:
        module_name = self.arguments[0]
        module = importlib.import_module(module_name)
        skip = set(self.options.get("skip", "").split())
        lines: list[str] = []
        for name in module.__all__:
            if name in skip:
                continue
            obj = getattr(module, name)
            if inspect.isclass(obj):
                lines += [f".. autoclass:: {module_name}.{name}", "   :members:", ""]
            elif callable(obj):
                lines += [f".. autofunction:: {module_name}.{name}", ""]
            else:
                lines += [f".. py:data:: {name}", f"   :module: {module_name}", f"   :value: {_short_repr(obj)}", ""]
                lines += [f"   {line}" for line in _attribute_doc(module_name, name, obj)] + [""]
        container = nodes.container()
        nested_parse_with_titles(self.state, StringList(lines, source=f"{module_name}.__all__"), container)
        return container.children


def _short_repr(obj: Any, width: int = 100) -> str:
    text = repr(obj)
    return text if len(text) <= width else text[: width - 4] + " ..."


def _attribute_doc(package: str, name: str, obj: Any) -> list[str]:
    """The ``#:`` comment (or docstring after the assignment) of ``name`` in the module of ``package``
    that defines it, or no line."""
    from sphinx.pycode import ModuleAnalyzer

    for modname, mod in sorted(sys.modules.items()):
        if not (modname == package or modname.startswith(package + ".")) or vars(mod).get(name, _MISSING) is not obj:
            continue
        try:
            docs = ModuleAnalyzer.for_module(modname).find_attr_docs()
        except Exception:  # noqa: BLE001 - no source to analyse
            continue
        if docs.get(("", name)):
            return [line for line in docs[("", name)] if line.strip()]
    return []


def setup(app: Sphinx) -> dict[str, Any]:
    app.add_directive("lidarpkt-formats", FormatsDirective)
    app.add_directive("lidarpkt-all", AllNamesDirective)
    app.connect("missing-reference", missing_reference)
    return {"version": "1", "parallel_read_safe": True, "parallel_write_safe": True}


__all__ = ["AllNamesDirective", "FormatsDirective", "cli_parser", "import_name", "missing_reference", "setup"]
