"""Mitsuba 3 XML → generic nodes, with every element's file and line.

One job, one file (over 600 lines on purpose): the parser's passes (defaults and ``$params``,
includes and paths, references, values, transforms) share one state (``_Parser``), and the
records they make (:class:`Prop`, :class:`Spectrum`, :class:`Node`, :class:`SceneWarning`)
are what its callers import with it.

This is the format layer only: it knows Mitsuba's XML *syntax and semantics* but no plugin.
:mod:`links1.scene.loader` turns the nodes into a :class:`links1.scene.scene.Scene`.

Supported, with Mitsuba's semantics:

* ``<scene version="x.y.z">`` (the root must carry a version; files older than 2.0 get their
  camelCase parameter names upgraded to snake_case, with a warning);
* ``$name`` references in *any* attribute value, filled from the ``params`` given to the
  parser (the ``-D name=value`` overrides) or from ``<default name=".." value=".."/>``;
  params override defaults; a reference to an undefined parameter is an error, and so is a
  param no ``$name`` takes (Mitsuba: "Found unused parameters");
* ``<include filename=".."/>`` (the included ``<scene>``'s children are spliced in) and
  ``<path value=".."/>`` (a search directory for every file named afterwards, relative to the
  file that names it); files are searched in the ``<path>`` directories (latest first), then
  in the main scene file's directory (as Mitsuba, also for files an included fragment names),
  then in the directory of the file that names them;
* ``id`` attributes, ``<ref id=".." name=".."/>`` (forward references allowed) and
  ``<alias id=".." as=".."/>``;
* value tags ``integer float boolean string point vector rgb spectrum transform``; ``point``
  / ``vector`` take ``x y z`` attributes (missing ones are 0) or ``value`` (one number is
  broadcast); ``rgb`` takes one or three numbers, comma- or space-separated; ``spectrum``
  takes one number or ``wavelength:value`` pairs (a :class:`Spectrum`, turned into RGB by
  :mod:`links1.shading.spectra` as Mitsuba's RGB variants do); ``<spectrum type="..">`` is an object
  (a spectrum plugin such as ``blackbody``), as in Mitsuba;
* ``<transform>`` with ``translate rotate scale matrix lookat`` children, each one
  *pre*-multiplied onto the transform so far (so the first child is applied first), exactly as
  Mitsuba: ``<translate x="1"/><rotate z="1" angle="90"/>`` gives ``R · T``.
  ``lookat`` without ``up`` uses the first vector of Mitsuba's ``coordinate_system(dir)``;
  ``rotate`` uses its axis as given, *not normalised* (as Mitsuba 3.9.1 does; a warning says so).

Every problem is a :class:`links1.errors.SceneError` naming the file, line and element.
Non-finite numbers (NaN, Inf) are rejected wherever a number is read.

Public API
----------
``parse_file(path, params=None, sources=None) -> Node`` and
``parse_string(text, base_dir=None, params=None, filename="<string>") -> Node`` return the
root ``<scene>`` :class:`Node`. A node has ``tag``, ``type``, ``id``, ``name``, ``file``,
``line``, ``props`` (name → :class:`Prop`) and ``children`` (list of ``(name, Node)`` for
the nested objects, references resolved, in document order); a top-level one also ``uses``,
the ``$name`` parameters it takes. ``sources`` (:class:`Sources`) keeps the files read, so the
next parse of the scene with other values reads none (:mod:`links1.scene.scenefile`).
"""
from __future__ import annotations

import math
import os
import re
import warnings
import xml.parsers.expat
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ..maths import transform as tf
from ..errors import SceneError
from .params import MAX_EXTENT, MAX_NESTING, MAX_VALUE
from ..shading.spectra import parse as parse_spectrum

#: Elements that are objects (plugins) in Mitsuba's XML.
OBJECT_TAGS = ("scene", "shape", "bsdf", "emitter", "sensor", "film", "sampler", "rfilter",
               "integrator", "texture", "medium", "phase", "volume")
#: Elements that are values (properties).
VALUE_TAGS = ("integer", "float", "boolean", "string", "point", "vector", "rgb", "spectrum",
              "transform")
TRANSFORM_OPS = ("translate", "rotate", "scale", "matrix", "lookat")

_PARAM_RE = re.compile(r"\$([A-Za-z_][A-Za-z0-9_]*)")
_MAX_INCLUDE_DEPTH = 32


class SceneWarning(UserWarning):
    """A scene feature the core approximates or ignores (the message names file:line)."""


def warn(message: str, file: str | None = None, line: int | None = None,
         element: str | None = None) -> None:
    """Emit a :class:`SceneWarning` formatted like a :class:`SceneError`."""
    warnings.warn(str(SceneError(message, file, line, element)), SceneWarning, stacklevel=3)


# --------------------------------------------------------------------------------------------
# records
# --------------------------------------------------------------------------------------------

@dataclass
class Prop:
    """One value property: ``kind`` is the tag (``float``, ``rgb``, ``transform``, ...)."""

    name: str
    kind: str
    value: Any
    file: str
    line: int

    def element(self) -> str:
        return f"<{self.kind} name='{self.name}'>"

    def error(self, message: str) -> SceneError:
        return SceneError(message, self.file, self.line, self.element())


@dataclass(frozen=True)
class Spectrum:
    """A ``<spectrum value=...>``: one number (``wavelengths`` None) or ``wavelength:value``
    pairs; :mod:`links1.shading.spectra` turns it into RGB the way the parameter's reader needs."""

    wavelengths: Any
    values: Any


@dataclass
class Node:
    """One object element (``<scene>``, ``<shape>``, ``<bsdf>``, ...)."""

    tag: str
    type: str | None
    id: str | None
    name: str | None
    file: str
    line: int
    props: dict = field(default_factory=dict)
    children: list = field(default_factory=list)  # [(name | None, Node)]
    #: directories searched for files this element names (``<path>`` entries, then its file's dir)
    search_dirs: tuple = ()
    #: a top-level element's ``$name`` parameters: those its element, its nested elements and the
    #: objects it references took (with the parameters their ``<default>`` values took), so other
    #: values of other parameters build the same object (links1.scene.scenefile); the root's: those
    #: taken outside its elements (its attributes, ``<include>`` filenames, ``<path>`` values)
    uses: frozenset = frozenset()

    # -- description / errors ------------------------------------------------------------
    def element(self) -> str:
        s = f"<{self.tag}"
        if self.type is not None:
            s += f" type='{self.type}'"
        if self.id is not None:
            s += f" id='{self.id}'"
        if self.name is not None:
            s += f" name='{self.name}'"
        return s + ">"

    def error(self, message: str) -> SceneError:
        return SceneError(message, self.file, self.line, self.element())

    def warn(self, message: str) -> None:
        warnings.warn(str(SceneError(message, self.file, self.line, self.element())),
                      SceneWarning, stacklevel=2)

    def objects(self, tag: str | None = None) -> list:
        """Nested objects (references resolved), optionally only those with ``tag``."""
        return [n for _, n in self.children if tag is None or n.tag == tag]

    def resolve(self, filename: str) -> str:
        """Find ``filename`` like Mitsuba's file resolver, or raise a SceneError."""
        found = _find_file(filename, self.search_dirs)
        if found is None:
            raise self.error(f"file not found: '{filename}' (searched {list(self.search_dirs)})")
        return found

    def __repr__(self) -> str:
        return f"Node({self.element()} at {self.file}:{self.line}, props={list(self.props)}, " \
               f"children={len(self.children)})"


@dataclass
class _Elem:
    """Raw XML element with its position (before any interpretation)."""

    tag: str
    attrs: dict
    file: str
    line: int
    children: list = field(default_factory=list)

    def element(self) -> str:
        s = f"<{self.tag}"
        for k in ("type", "id", "name"):
            if k in self.attrs:
                s += f" {k}='{self.attrs[k]}'"
        return s + ">"

    def error(self, message: str) -> SceneError:
        return SceneError(message, self.file, self.line, self.element())


@dataclass
class _Ref:
    id: str
    name: str | None
    elem: _Elem


# --------------------------------------------------------------------------------------------
# raw XML with line numbers (expat)
# --------------------------------------------------------------------------------------------

def _read_xml(data: bytes | str, filename: str) -> _Elem:
    parser = xml.parsers.expat.ParserCreate()
    stack: list[_Elem] = []
    root: list[_Elem] = []

    def start(tag, attrs):
        e = _Elem(tag, dict(attrs), filename, parser.CurrentLineNumber)
        if len(stack) >= MAX_NESTING:   # the reader and the loader recurse per level
            raise SceneError(f"elements nested deeper than {MAX_NESTING} levels", filename, e.line, e.element())
        if stack:
            stack[-1].children.append(e)
        else:
            root.append(e)
        stack.append(e)

    def end(tag):
        stack.pop()

    parser.StartElementHandler = start
    parser.EndElementHandler = end
    try:
        parser.Parse(data, True)
    except xml.parsers.expat.ExpatError as exc:
        msg = xml.parsers.expat.errors.messages.get(exc.code, str(exc))
        if stack:  # name the element that is still open (what a mismatched/missing end tag breaks)
            open_elem = stack[-1]
            raise SceneError(f"malformed XML: {msg} (column {exc.offset + 1}); element opened at "
                             f"line {open_elem.line} is not closed properly", filename, exc.lineno,
                             open_elem.element()) from None
        raise SceneError(f"malformed XML: {msg} (column {exc.offset + 1})", filename,
                         exc.lineno, "<xml>") from None
    if not root:  # pragma: no cover - expat reports 'no element found' first
        raise SceneError("empty XML document", filename, 1, "<xml>")
    return root[0]


def _find_file(filename: str, dirs) -> str | None:
    if os.path.isabs(filename):
        return filename if os.path.isfile(filename) else None
    for d in dirs:
        p = os.path.join(d, filename)
        if os.path.isfile(p):
            return os.path.normpath(p)
    return None


# --------------------------------------------------------------------------------------------
# number parsing
# --------------------------------------------------------------------------------------------

def _split_numbers(text: str) -> list[str]:
    return [t for t in re.split(r"[,\s]+", text.strip()) if t]


def _float(text: str, elem: _Elem, what: str) -> float:
    try:
        v = float(text)
    except (TypeError, ValueError):
        raise elem.error(f"{what}: cannot parse '{text}' as a number") from None
    if not math.isfinite(v):
        raise elem.error(f"{what}: value must be finite, got '{text}'")
    if abs(v) > MAX_VALUE:
        raise elem.error(f"{what}: |value| must be <= {MAX_VALUE:g} (float32's reach), got '{text}'")
    return v


def _floats(text: str, elem: _Elem, what: str, counts=(3,)) -> np.ndarray:
    toks = _split_numbers(text)
    if len(toks) not in counts:
        want = " or ".join(str(c) for c in counts)
        raise elem.error(f"{what}: expected {want} numbers, got {len(toks)} ('{text}')")
    return np.array([_float(t, elem, what) for t in toks], dtype=np.float64)


def _xyz(elem: _Elem, default: float, allow_single: bool = True) -> np.ndarray:
    """``value="x, y, z"`` (or one number, broadcast) or ``x= y= z=`` attributes."""
    a = elem.attrs
    if "value" in a:
        counts = (1, 3) if allow_single else (3,)
        v = _floats(a["value"], elem, "value", counts)
        return np.broadcast_to(v, (3,)).astype(np.float64)
    return np.array([_float(a[k], elem, k) if k in a else default for k in ("x", "y", "z")])


def _coordinate_system_s(n: np.ndarray) -> np.ndarray:
    """First vector of Mitsuba's ``coordinate_system(n)`` (Duff et al. 2017)."""
    sign = math.copysign(1.0, n[2])
    a = -1.0 / (sign + n[2])
    b = n[0] * n[1] * a
    return np.array([math.copysign(n[0] * n[0] * a, n[2]) + 1.0, math.copysign(b, n[2]),
                     -math.copysign(n[0], n[2])])


# --------------------------------------------------------------------------------------------
# the parser
# --------------------------------------------------------------------------------------------

class Sources:
    """The files a parse read (the scene file, its includes), kept in memory for the next parse
    of the same scene with other values (:class:`links1.scene.scenefile.SceneFile`: a sequence's
    frames do not read the disk again). ``reads`` counts the files read from the disk."""

    def __init__(self):
        self.data: dict = {}     # path -> bytes
        self.found: dict = {}    # (filename, search dirs) -> path
        self.reads = 0

    def read(self, path: str) -> bytes:
        if path not in self.data:
            with open(path, "rb") as f:
                self.data[path] = f.read()
            self.reads += 1
        return self.data[path]


class _Parser:
    def __init__(self, params: dict | None, sources: Sources | None = None):
        self.params = {k: _param_str(v) for k, v in (params or {}).items()}
        self.sources = sources or Sources()
        self.used_params: set = set()  # the params some ``$name`` took (Mitsuba refuses the others)
        # the parameters taken while reading: per top-level element (its set while it is read),
        # outside them (root_uses: the root, <include> filenames, <path>s), per <default> and per id
        self.root_uses: set = set()
        self.uses: set = self.root_uses
        self.default_uses: dict[str, set] = {}
        self.id_uses: dict[str, set] = {}
        self.ref_uses: list[tuple[set, str]] = []
        self.root: Node | None = None
        self.defaults: dict[str, str] = {}
        self.ids: dict[str, Any] = {}
        self.refs: list[tuple[Node, int, _Ref]] = []
        self.search_dirs: list[str] = []  # <path> entries, latest first
        self.include_stack: list[str] = []
        self.depth = 0   # objects open now, across <include>s (MAX_NESTING)
        self.upgrade_names = False
        self.base_dir: str | None = None
        self.root_dir: str | None = None  # the main scene file's directory

    # -- parameters ------------------------------------------------------------------------
    def lookup(self, name: str) -> str | None:
        self.uses.add(name)
        if name in self.params:
            self.used_params.add(name)
            return self.params[name]
        self.uses.update(self.default_uses.get(name, ()))
        return self.defaults.get(name)

    def subst(self, elem: _Elem) -> None:
        """Replace ``$name`` in every attribute of ``elem`` (in place)."""
        for k, v in elem.attrs.items():
            if "$" not in v:
                continue

            def repl(m, k=k):
                val = self.lookup(m.group(1))
                if val is None:
                    raise elem.error(f"undefined parameter '${m.group(1)}' in attribute '{k}' "
                                     f"(give it with -D {m.group(1)}=... or a <default>)")
                return val

            elem.attrs[k] = _PARAM_RE.sub(repl, v)

    def collect_defaults(self, root: _Elem) -> None:
        for c in root.children:
            if c.tag == "default":
                outer, taken = self.uses, set()
                self.uses = taken
                try:
                    self.subst(c)
                finally:
                    self.uses = outer
                name, value = c.attrs.get("name"), c.attrs.get("value")
                if not name or value is None:
                    raise c.error("<default> needs 'name' and 'value' attributes")
                self.defaults.setdefault(name, value)
                self.default_uses.setdefault(name, taken)

    # -- files -----------------------------------------------------------------------------
    def file_dir(self, file: str) -> str:
        if file.startswith("<"):  # a string: its directory is base_dir
            return os.path.abspath(self.base_dir or os.getcwd())
        return os.path.dirname(os.path.abspath(file))

    def dirs_for(self, file: str) -> tuple:
        """Where a file named in ``file`` is looked for: the ``<path>`` directories, the main
        scene file's directory (Mitsuba resolves the files an ``<include>``d fragment names
        there), then ``file``'s own directory."""
        dirs = list(self.search_dirs)
        for d in (self.root_dir, self.file_dir(file)):
            if d is not None and d not in dirs:
                dirs.append(d)
        return tuple(dirs)

    def parse_root(self, data, filename: str, base_dir: str | None) -> Node:
        raw = _read_xml(data, filename)
        if raw.tag != "scene":
            raise raw.error(f"the root element must be <scene>, got <{raw.tag}>")
        self.base_dir = base_dir
        self.root_dir = self.file_dir(filename)
        self.subst(raw)
        self.subst_version(raw)
        self.collect_defaults(raw)
        node = self.object(raw)
        self.resolve_refs()
        self.check_unused_params(raw)
        self.close_uses(node)
        return node

    def close_uses(self, root: Node) -> None:
        """Each top-level element's ``uses`` with those of the objects it references (through
        references of references too), frozen."""
        changed = True
        while changed:
            changed = False
            for taken, ident in self.ref_uses:
                more = self.id_uses.get(ident, set()) - taken
                if more:
                    taken |= more
                    changed = True
        for _, child in root.children:
            if isinstance(child, Node):
                child.uses = frozenset(child.uses)
        root.uses = frozenset(self.root_uses)

    def check_unused_params(self, raw: _Elem) -> None:
        """Refuse a ``-D name=value`` that no ``$name`` of the scene (or its includes) takes,
        as Mitsuba's parser does ("Found unused parameters"), naming the file."""
        unused = [k for k in self.params if k not in self.used_params]
        if unused:
            given = ", ".join(f"-D {k}={self.params[k]}" for k in unused)
            names = ", ".join(f"${k}" for k in unused)
            raise SceneError(f"unused parameter{'s' if len(unused) > 1 else ''} {given}: the scene "
                             f"has no {names} (Mitsuba refuses unused parameters)",
                             raw.file, raw.line, "<scene>")

    def subst_version(self, raw: _Elem) -> None:
        ver = raw.attrs.get("version")
        if ver is None:
            raise raw.error("missing 'version' attribute (e.g. <scene version=\"3.0.0\">)")
        try:
            major = int(ver.strip().split(".")[0])
        except ValueError:
            raise raw.error(f"bad version '{ver}' (expected e.g. '3.0.0')") from None
        if major < 2:
            self.upgrade_names = True
            warn(f"scene version {ver} is older than 2.0: camelCase parameter names are "
                 "upgraded to snake_case", raw.file, raw.line, raw.element())

    # -- elements --------------------------------------------------------------------------
    def object(self, elem: _Elem) -> Node:
        a = elem.attrs
        name = a.get("name")
        if name is not None and self.upgrade_names:
            name = _snake(name)
        node = Node(elem.tag, a.get("type"), a.get("id"), name, elem.file, elem.line,
                    search_dirs=self.dirs_for(elem.file))
        if self.root is None:
            self.root = node
        if elem.tag != "scene" and node.type is None:
            raise elem.error(f"<{elem.tag}> needs a 'type' attribute")
        if node.id is not None:
            self.register(node.id, node, elem)
        # objects nest across <include>s too: the same limit on the whole chain
        self.depth += 1
        try:
            if self.depth > MAX_NESTING:
                raise elem.error(f"elements nested deeper than {MAX_NESTING} levels (with the <include>s)")
            self.body(elem, node)
        finally:
            self.depth -= 1
        return node

    def register(self, ident: str, obj, elem: _Elem, uses: set | None = None) -> None:
        if ident in self.ids:
            prev = self.ids[ident]
            raise elem.error(f"duplicate id '{ident}' (first defined at {prev.file}:{prev.line})")
        self.ids[ident] = obj
        # what building it takes: the parameters of the top-level element it is read in
        self.id_uses[ident] = self.uses if uses is None else uses

    def body(self, elem: _Elem, node: Node) -> None:
        top = node is self.root     # the scene's own elements (those of its includes too)
        for c in elem.children:
            if c.tag == "default":
                if elem.tag != "scene":
                    raise c.error("<default> is only allowed directly inside <scene>")
                continue  # collected up front
            if top:
                taken = self.uses = set()
            child = self.element(c, node)
            if top:
                if child is not None:
                    child.uses = taken
                else:           # <include>, <path>, <alias>, ...: what the whole scene takes
                    self.root_uses |= taken
                self.uses = self.root_uses

    def element(self, c: _Elem, node: Node) -> Node | None:
        """Read one child ``c`` of ``node``'s element; the object it is, if it is one."""
        self.subst(c)
        if c.tag in OBJECT_TAGS or (c.tag == "spectrum" and "type" in c.attrs):
            if c.tag == "scene":
                raise c.error("<scene> cannot be nested")
            child = self.object(c)
            node.children.append((child.name, child))
            return child
        elif c.tag in VALUE_TAGS:
            prop = self.value(c)
            if prop.name in node.props:
                prev = node.props[prop.name]
                raise c.error(f"property '{prop.name}' given twice (also at {prev.file}:{prev.line})")
            node.props[prop.name] = prop
        elif c.tag == "ref":
            ident = c.attrs.get("id")
            if not ident:
                raise c.error("<ref> needs an 'id' attribute")
            name = c.attrs.get("name")
            node.children.append((name, None))
            self.refs.append((node, len(node.children) - 1, _Ref(ident, name, c)))
            self.ref_uses.append((self.uses, ident))
        elif c.tag == "include":
            self.include(c, node)
        elif c.tag == "path":
            value = c.attrs.get("value")
            if value is None:
                raise c.error("<path> needs a 'value' attribute")
            d = value if os.path.isabs(value) else os.path.join(self.file_dir(c.file), value)
            if not os.path.isdir(d):
                raise c.error(f"directory not found: '{value}'")
            self.search_dirs.insert(0, os.path.normpath(d))
        elif c.tag == "alias":
            src, dst = c.attrs.get("id"), c.attrs.get("as")
            if not src or not dst:
                raise c.error("<alias> needs 'id' and 'as' attributes")
            if src not in self.ids:
                raise c.error(f"<alias>: unknown id '{src}'")
            self.register(dst, self.ids[src], c, uses=self.id_uses.get(src))
        elif c.tag in TRANSFORM_OPS:
            raise c.error(f"<{c.tag}> is only allowed inside <transform>")
        else:
            raise c.error(f"unknown element <{c.tag}>")
        return None

    def include(self, c: _Elem, node: Node) -> None:
        fn = c.attrs.get("filename")
        if not fn:
            raise c.error("<include> needs a 'filename' attribute")
        where = (fn, self.dirs_for(c.file))
        path = self.sources.found.get(where) or _find_file(*where)
        if path is None:
            raise c.error(f"file not found: '{fn}'")
        self.sources.found[where] = path
        if path in self.include_stack or len(self.include_stack) >= _MAX_INCLUDE_DEPTH:
            raise c.error(f"recursive <include> of '{fn}'")
        try:
            data = self.sources.read(path)
        except OSError as exc:
            raise c.error(f"cannot read '{fn}': {exc.strerror}") from None
        raw = _read_xml(data, path)
        self.include_stack.append(path)
        try:
            if raw.tag == "scene":
                self.collect_defaults(raw)
                self.body(raw, node)
            else:
                wrapper = _Elem("scene", {}, raw.file, raw.line, [raw])
                self.body(wrapper, node)
        finally:
            self.include_stack.pop()

    def resolve_refs(self) -> None:
        for node, idx, ref in self.refs:
            target = self.ids.get(ref.id)
            if target is None:
                raise ref.elem.error(f"reference to unknown id '{ref.id}'")
            if not isinstance(target, Node):
                raise ref.elem.error(f"id '{ref.id}' does not name an object")
            node.children[idx] = (ref.name, target)

    # -- values ----------------------------------------------------------------------------
    def value(self, c: _Elem) -> Prop:
        name = c.attrs.get("name")
        if not name:
            raise c.error(f"<{c.tag}> needs a 'name' attribute")
        if self.upgrade_names:
            name = _snake(name)
        tag = c.tag
        if tag == "transform":
            return Prop(name, tag, self.transform(c), c.file, c.line)
        if tag in ("point", "vector"):
            return Prop(name, tag, _xyz(c, 0.0), c.file, c.line)
        if "value" not in c.attrs:
            if tag == "spectrum" and "filename" in c.attrs:
                raise c.error("spectra from files are not supported by the core")
            raise c.error(f"<{tag}> needs a 'value' attribute")
        text = c.attrs["value"]
        if tag == "integer":
            try:
                v = int(text.strip())
            except ValueError:
                raise c.error(f"cannot parse '{text}' as an integer") from None
            if not -2 ** 63 <= v < 2 ** 63:
                raise c.error(f"integer '{text}' does not fit 64 bits")
            return Prop(name, tag, v, c.file, c.line)
        if tag == "float":
            return Prop(name, tag, _float(text, c, "value"), c.file, c.line)
        if tag == "boolean":
            t = text.strip().lower()
            if t not in ("true", "false"):
                raise c.error(f"cannot parse '{text}' as a boolean (true or false)")
            return Prop(name, tag, t == "true", c.file, c.line)
        if tag == "string":
            return Prop(name, tag, text, c.file, c.line)
        if tag == "rgb":
            v = _floats(text, c, "value", (1, 3))
            return Prop(name, tag, np.broadcast_to(v, (3,)).copy(), c.file, c.line)
        if tag == "spectrum":
            try:
                wavelengths, values = parse_spectrum(text)
            except ValueError as exc:
                raise c.error(str(exc)) from None
            return Prop(name, tag, Spectrum(wavelengths, values), c.file, c.line)
        raise c.error(f"unknown element <{tag}>")  # pragma: no cover

    def transform(self, c: _Elem) -> np.ndarray:
        m = np.eye(4)
        for op in c.children:
            self.subst(op)
            a = op.attrs
            try:
                if op.tag == "translate":
                    step = tf.translate(_xyz(op, 0.0))
                elif op.tag == "scale":
                    step = tf.scale(_xyz(op, 1.0))
                elif op.tag == "rotate":
                    if "angle" not in a:
                        raise op.error("<rotate> needs an 'angle' attribute")
                    axis = _xyz(op, 0.0, allow_single=False)
                    if not np.any(axis != 0):
                        raise op.error("rotation axis must be non-zero (give x, y, z or value)")
                    if abs(float(np.linalg.norm(axis)) - 1.0) > 1e-6:
                        warn(f"rotation axis {axis.tolist()} is not unit length; like Mitsuba, the "
                             "core does not normalise it (the matrix is not a pure rotation)",
                             op.file, op.line, op.element())
                    step = _rotate_raw(axis, _float(a["angle"], op, "angle"))
                elif op.tag == "matrix":
                    if "value" not in a:
                        raise op.error("<matrix> needs a 'value' attribute (16 or 9 numbers)")
                    v = _floats(a["value"], op, "value", (16, 9))
                    step = np.eye(4)
                    if v.size == 16:
                        step = v.reshape(4, 4)
                    else:
                        step[:3, :3] = v.reshape(3, 3)
                elif op.tag == "lookat":
                    if "origin" not in a or "target" not in a:
                        raise op.error("<lookat> needs 'origin' and 'target' attributes")
                    origin = _floats(a["origin"], op, "origin")
                    target = _floats(a["target"], op, "target")
                    if "up" in a and a["up"].strip():
                        up = _floats(a["up"], op, "up")
                    else:
                        d = target - origin
                        nd = np.linalg.norm(d)
                        if not nd > 0:
                            raise op.error("lookat: origin and target coincide")
                        up = _coordinate_system_s(d / nd)
                    step = tf.look_at(origin, target, up)
                else:
                    raise op.error(f"unknown element <{op.tag}> inside <transform> "
                                   f"(allowed: {', '.join(TRANSFORM_OPS)})")
            except ValueError as exc:
                if isinstance(exc, SceneError):
                    raise
                raise op.error(str(exc)) from None
            m = step @ m  # Mitsuba pre-multiplies: the first child acts first
            if not (np.all(np.isfinite(m)) and float(np.max(np.abs(m))) <= MAX_EXTENT):
                raise op.error(f"the transform's entries must be finite and <= {MAX_EXTENT:g} in "
                               f"magnitude, got {float(np.max(np.abs(m))):g}")
        return m


def _rotate_raw(axis: np.ndarray, angle_deg: float) -> np.ndarray:
    """Mitsuba's ``Transform4f::rotate``: Rodrigues' matrix of the axis *as given* (not normalised)."""
    return tf.rotate(axis, angle_deg, normalize_axis=False)


def _snake(name: str) -> str:
    return re.sub(r"(?<=[a-z0-9])([A-Z])", lambda m: "_" + m.group(1).lower(), name)


def _param_str(v) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, (list, tuple, np.ndarray)):
        return ", ".join(_param_str(x) for x in np.ravel(v))
    if isinstance(v, float):
        return repr(v)
    return str(v)


# --------------------------------------------------------------------------------------------
# public entry points
# --------------------------------------------------------------------------------------------

def parse_file(path, params: dict | None = None, sources: Sources | None = None) -> Node:
    """Parse a Mitsuba 3 XML scene file into its root ``<scene>`` :class:`Node`.

    ``params`` are the ``-D name=value`` overrides (values are turned into strings);
    ``sources``: the files an earlier parse of this scene read (:class:`Sources`), not read again.
    """
    path = os.fspath(path)
    sources = sources or Sources()
    try:
        data = sources.read(path)
    except OSError as exc:
        raise SceneError(f"cannot read scene file: {exc.strerror}", path, None, "<scene>") from None
    return _Parser(params, sources).parse_root(data, path, None)


def parse_string(text: str, base_dir=None, params: dict | None = None,
                 filename: str = "<string>") -> Node:
    """Parse XML text; relative file names are searched in ``base_dir`` (default: cwd)."""
    base = os.fspath(base_dir) if base_dir is not None else os.getcwd()
    return _Parser(params).parse_root(text, filename, base)
