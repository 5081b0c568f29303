"""Load links1 / Mitsuba XML into a :class:`mitsuba.Scene` rendered by ``links1_whitted``.

``mi.parser`` parses the file; ``links1_quadric`` and ``links1_blob`` nodes are taken out
before instantiation (Mitsuba 3.9.1 has no Python shapes) and handed to the integrator, their
BSDFs travel to it as nested objects. ``links1_bicubic`` stays: it is a registered
:class:`mitsuba.Mesh` plugin. The same XML files as the core are read unchanged.
"""
from __future__ import annotations

import os
import re
import warnings

import numpy as np

from ._registry import register
from .util import PLACE_PROPERTY, PLACED_PLUGINS, place_of
from .util import read_rgb as _rgb
from .blob import BlobSpec
from .shapes import QuadricSpec

CUSTOM = ("links1_quadric", "links1_blob")
#: What ``links1_integrator="scene"`` renders a file without ``<integrator>`` with: Mitsuba 3 has no
#: default (``mi.render`` raises "No integrator specified!"); Mitsuba 2 instantiated ``path``.
DEFAULT_SCENE_INTEGRATOR = "path"
SLOT_ID = "_links1_slot_{}"


def _flatten_instances(state) -> None:
    """Replace each ``instance`` by copies of its ``shapegroup``'s shapes, each mapped by the
    instance's ``to_world`` after its own, in the instance's place in file order (shape slots
    are file order), and drop the groups: what the core does (links1.scene.loader). links1_whitted
    then sees ordinary shapes (its per-shape tables hold one row per shape; a hit on a shape
    shared by instances would not say which copy it is)."""
    import mitsuba as mi
    nodes = state.nodes
    R = mi.Properties.ResolvedReference
    by_id = {nodes[i].props.id(): i for i in range(len(nodes)) if nodes[i].props.id()}

    def shape_node(v):
        i = v.index() if isinstance(v, R) else by_id.get(v.id()) if isinstance(v, mi.Properties.Reference) else None
        return None if i is None or nodes[i].type != mi.ObjectType.Shape else i

    root = nodes[0]
    entries = [(k, root.props[k]) for k in root.props.keys()]
    kinds = [nodes[i].props.plugin_name() if (i := shape_node(v)) is not None else None for _, v in entries]
    if "instance" not in kinds and "shapegroup" not in kinds:
        return
    def groups_of(inst):
        gs = [shape_node(inst.props[q]) for q in inst.props.keys()
              if isinstance(inst.props[q], (R, mi.Properties.Reference))]
        return [g for g in gs if g is not None and nodes[g].props.plugin_name() == "shapegroup"]

    def kept(g):
        # an sdfgrid cannot be mapped by a rotating to_world (Mitsuba: "use instancing"): its
        # group stays instanced, and links1_whitted shades the members' hits (tables.group_members)
        return any(nodes[m].props.plugin_name() == "sdfgrid" for q in nodes[g].props.keys()
                   if (m := shape_node(nodes[g].props[q])) is not None)

    copies, order = [], []        # new nodes (made before any append), the root's new entries
    for (k, v), kind in zip(entries, kinds):
        if kind == "shapegroup":
            if kept(shape_node(v)):
                order.append((k, v))
            continue
        if kind != "instance":
            order.append((k, v))
            continue
        inst = nodes[shape_node(v)]
        groups = groups_of(inst)
        if len(groups) != 1:
            raise ValueError(f"{_where(state, inst)}: an instance needs exactly one shapegroup")
        if kept(groups[0]):
            order.append((k, v))
            continue
        outer = inst.props["to_world"] if "to_world" in inst.props else mi.ScalarAffineTransform4d()
        group = nodes[groups[0]]
        for j, q in enumerate(group.props.keys()):
            m = shape_node(group.props[q])
            if m is None:
                continue
            member = nodes[m]
            if member.props.plugin_name() in ("shapegroup", "instance"):
                raise ValueError(f"{_where(state, member)}: nested instancing is not supported (as in Mitsuba)")
            node = mi.parser.SceneNode()
            node.type, node.file_index, node.offset = member.type, member.file_index, member.offset
            node.props = mi.Properties(member.props)
            node.props["to_world"] = outer @ member.props["to_world"] if "to_world" in member.props else outer
            if node.props.id():
                node.props.set_id("")
            copies.append(node)
            order.append((f"{k}_{j}", len(copies) - 1))
    base = len(nodes)
    for node in copies:
        nodes.append(node)
    root = nodes[0]   # the appends may have moved the node vector
    for k, _ in entries:
        del root.props[k]
    for k, v in order:
        root.props[k] = R(base + v) if isinstance(v, int) else v


def _prepare_state(state, config, integrator: str, base_dir: str | None):
    import mitsuba as mi
    if integrator != "scene":
        _flatten_instances(state)
    nodes = state.nodes
    root = state.nodes[0]
    refs = mi.Properties.ResolvedReference, mi.Properties.Reference
    integ_node = None
    custom_specs = []
    custom_nodes = []
    moved_refs = []
    # BSDFs declared at the top of the file (referenced by id): mi.traverse names them by their
    # own id already; the integrator's traverse leaves them out
    top_level = {root.props[k].index() for k in root.props.keys()
                 if isinstance(root.props[k], mi.Properties.ResolvedReference)}
    slot_of_id = {}
    names = []
    slot = 0
    for key in list(root.props.keys()):
        ref = root.props[key]
        if not isinstance(ref, mi.Properties.ResolvedReference):
            continue
        node = nodes[ref.index()]
        ptype, pname = node.type, node.props.plugin_name()
        if ptype == mi.ObjectType.Integrator:
            if integ_node is None:
                integ_node = node
            continue
        if ptype != mi.ObjectType.Shape:
            continue
        props = node.props
        if pname in CUSTOM:
            try:
                spec = (QuadricSpec if pname == "links1_quadric" else BlobSpec).from_props(slot, props)
            except ValueError as exc:
                raise ValueError(f"{_where(state, node)}: {exc}") from None
            spec.where = _where(state, node)    # (for a params.update() that it refuses)
            for k in list(props.keys()):
                v = props[k]
                if isinstance(v, refs):
                    child = nodes[v.index()] if isinstance(v, mi.Properties.ResolvedReference) else None
                    if child is not None and child.type == mi.ObjectType.Emitter:
                        if child.props.plugin_name() != "area":
                            raise ValueError(f"{_where(state, child)}: only 'area' emitters can be nested in a shape")
                        spec.emission = _rgb(child.props, "radiance", 1.0)
                        warnings.warn(f"{_where(state, child)}: <emitter type='area'> in <shape type="
                                      f"'{pname}'>: its area emitter is shown where the shape is seen "
                                      "directly; it does not light the scene", stacklevel=3)
                        child.props.set_plugin_name("constant")  # harmless, never referenced
                        continue
                    if child is None or child.type == mi.ObjectType.BSDF:
                        moved_refs.append((f"_l1_bsdf_{slot}", v))
                        if child is None or v.index() in top_level:   # <ref id=...>: a named BSDF
                            moved_refs.append((f"_l1_topbsdf_{slot}", True))
            del root.props[key]
            custom_specs.append(spec)
            custom_nodes.append((slot, node))
            names.append((slot, props.id() or f"{pname}_{slot}", pname))
        else:
            if pname in ("rectangle", "disk") and "to_world" in props:
                _planar_to_world(props)
            if not props.id():
                props.set_id(SLOT_ID.format(slot))
            slot_of_id[props.id()] = slot
            names.append((slot, props.id(), pname))
            if pname == "links1_bicubic" and base_dir:
                fdir = base_dir
                try:
                    fdir = os.path.dirname(str(state.files[node.file_index])) or base_dir
                except Exception:
                    pass
                props["_links1_base_dir"] = fdir
        slot += 1
    if integrator == "scene":
        for _, node in custom_nodes:
            warnings.warn(f"{_where(state, node)}: <shape type='{node.props.plugin_name()}'>: "
                          "the file's own integrator (--integrator scene, links1_integrator='scene') "
                          "cannot see this shape; it is left out", stacklevel=3)
        if integ_node is None:
            warnings.warn(f"{_where(state, root)}: <scene>: the scene names no integrator (Mitsuba 3.9.1 "
                          f"would refuse to render it): using '{DEFAULT_SCENE_INTEGRATOR}' with "
                          "Mitsuba's defaults, the default integrator of Mitsuba before 3.0",
                          stacklevel=3)
            _add_integrator(state, DEFAULT_SCENE_INTEGRATOR)
        return None, custom_specs, slot_of_id, names
    if integ_node is None:
        integ_node = _add_integrator(state, "links1_whitted")
    else:
        old = integ_node.props.plugin_name()
        keep = {"max_depth", "seed", "aovs", "min_weight", "light_samples", "adaptive", "adaptive_depth",
                "projective"}
        if old != "links1_whitted":
            keep = {"max_depth"}
            if "max_depth" not in integ_node.props:
                # a wrapper (moment, aov) without a depth of its own: its nested integrator's,
                # as the core reads it
                for k in integ_node.props.keys():
                    v = integ_node.props[k]
                    if isinstance(v, mi.Properties.ResolvedReference):
                        inner = nodes[v.index()]
                        if inner.type == mi.ObjectType.Integrator and "max_depth" in inner.props:
                            integ_node.props["max_depth"] = inner.props["max_depth"]
                            break
        for k in list(integ_node.props.keys()):
            if k not in keep:
                del integ_node.props[k]
        integ_node.props.set_plugin_name("links1_whitted")
    if not integ_node.props.id() or integ_node.props.id().startswith("_unnamed"):
        integ_node.props.set_id("links1_whitted")   # mi.traverse's prefix of the links1 shapes' BSDFs
    for k, v in moved_refs:
        integ_node.props[k] = v
    return integ_node, custom_specs, slot_of_id, names


def _planar_to_world(props) -> None:
    """A rectangle or disk scaled to zero thickness is still that shape: give its to_world
    a usable third column (:func:`links1.scene.params.planar_to_world`, as the core does) where
    Mitsuba would derive NaN normals from the singular map."""
    import mitsuba as mi

    from links1.scene.params import planar_to_world
    m = np.array(props["to_world"].matrix, dtype=np.float64).reshape(4, 4)
    fixed = planar_to_world(m)
    if not np.array_equal(fixed, m):
        props["to_world"] = mi.ScalarAffineTransform4d(mi.ScalarMatrix4d(fixed))


def _add_integrator(state, plugin: str):
    """Append an integrator node to the parsed scene and reference it from the root."""
    import mitsuba as mi
    nodes = state.nodes
    node = mi.parser.SceneNode()
    node.type = mi.ObjectType.Integrator
    node.props = mi.Properties(plugin)
    nodes.append(node)
    # The append may reallocate the C++ node vector: earlier references into it (such as
    # the root) dangle, so fetch the root again before writing to it.
    nodes[0].props["_links1_integrator"] = mi.Properties.ResolvedReference(len(nodes) - 1)
    return nodes[len(nodes) - 1]


#: Mitsuba's mesh files, whose reader computes smooth vertex normals where the file stores none
#: (``Mesh::recompute_vertex_normals``)
MESH_FILES = ("ply", "obj", "serialized")


def _mesh_files(state) -> dict:
    """Shape id -> (plugin, resolved file name, shape_index) of every mesh-file node that will
    have vertex normals (not ``face_normals``), while the file resolver still holds the scene's
    paths."""
    import mitsuba as mi
    out = {}
    fr = mi.file_resolver()
    for node in state.nodes:
        props = node.props
        if node.type != mi.ObjectType.Shape or props.plugin_name() not in MESH_FILES or not props.id():
            continue
        if "filename" not in props or ("face_normals" in props and bool(props["face_normals"])):
            continue
        index = int(props["shape_index"]) if "shape_index" in props else 0
        out[props.id()] = (props.plugin_name(), str(fr.resolve(str(props["filename"]))), index)
    return out


def _settle_normals(scene, mesh_files: dict, places=None) -> None:
    """Vertex normals that are the same bits on every load.

    Mitsuba computes a mesh file's missing normals (``Mesh::recompute_vertex_normals``) with
    float32 atomic scatter-adds over Dr.Jit's threads: the order of each vertex's sum, and so
    its last bits, change from load to load (the image of a PLY without normals differed in a
    few pixels run to run). Such normals are computed again on one thread, in face order
    (:func:`.normals.recompute`; a ``params.update()`` that moves the vertices gets the same
    before the next frame: :func:`.normals.settle_moved`). Mitsuba 3.9.1's OBJ reader also
    flags normals when a file has ``vn`` lines that no face references, and leaves them
    uninitialised: those are recomputed the same way, with a warning. LLVM variants only: a
    scalar variant sums in face order already, and a CUDA variant's atomics keep their order
    whatever Dr.Jit's thread count (its normals vary as Mitsuba's)."""
    import mitsuba as mi

    from links1.geometry.mesh_files import stores_normals

    from . import normals
    llvm = normals.llvm()
    redo = []
    for s in scene.shapes():
        if not (s.is_mesh() and s.has_vertex_normals()):
            continue
        prm = mi.traverse(s)
        if "vertex_normals" not in prm.keys():
            continue
        n = np.array(prm["vertex_normals"], dtype=np.float64).reshape(-1, 3)
        ln = np.linalg.norm(n, axis=1)
        if n.size and not (np.all(np.isfinite(ln)) and np.all(np.abs(ln - 1.0) < 1e-3)):
            warnings.warn(f"{place_of(s, places) or repr(s.id())}: invalid vertex normals from Mitsuba's reader "
                          "(unreferenced 'vn' lines?); recomputed", stacklevel=3)
            redo.append(s)
        elif s.id() in mesh_files and llvm:
            kind, path, index = mesh_files[s.id()]
            try:
                if not stores_normals(path, kind, index):
                    redo.append(s)
            except ValueError:
                pass   # Mitsuba read it: its normals stay as Mitsuba made them
    normals.recompute(redo)


def _where(state, node) -> str:
    """``FILE:LINE`` of a parsed node (Mitsuba keeps the byte offset), as the core's messages."""
    try:
        path = str(state.files[node.file_index])
    except Exception:
        return "scene"
    try:
        with open(path, "rb") as f:
            line = f.read(int(node.offset)).count(b"\n") + 1
        return f"{path}:{line}"
    except (OSError, TypeError, ValueError):
        return f"{path} (offset {node.offset})"


_TAGS = {"BSDF": "bsdf", "Emitter": "emitter", "Film": "film", "Integrator": "integrator",
         "Medium": "medium", "PhaseFunction": "phase", "ReconstructionFilter": "rfilter",
         "Sampler": "sampler", "Scene": "scene", "Sensor": "sensor", "Shape": "shape",
         "Texture": "texture", "Volume": "volume"}
#: the id given to an object the file names none for, so that a warning can find its element
#: (Scene.traverse names ``_unnamed_*`` objects generically, as objects without an id)
UNNAMED_ID = "_unnamed_links1_{}"


def _ref_names(nodes) -> dict:
    """Node index -> the name its parent gives it (``<bsdf name='..'>``), where one was given."""
    import mitsuba as mi
    names = {}
    for n in nodes:
        for k in n.props.keys():
            if k.startswith("_") or n.props.type(k) != mi.Properties.Type.ResolvedReference:
                continue
            was = n.props.was_queried(k)
            names.setdefault(n.props[k].index(), k)
            n.props.mark_queried(k, was)   # reading marks it: Mitsuba must still see what it was
    return names


def _element(node, user_id: str, name: str | None) -> str:
    """``<tag type='..' id='..' name='..'>`` of a parsed node, as the core's messages write it."""
    elem = f"<{_TAGS.get(node.type.name, node.type.name.lower())} type='{node.props.plugin_name()}'"
    if user_id:
        elem += f" id='{user_id}'"
    if name:
        elem += f" name='{name}'"
    return elem + ">"


def _source(state, node, text, cache) -> tuple:
    """``(path, bytes or None)`` of the file a node comes from (``text``: a string's scene)."""
    path = str(state.files[node.file_index])
    if path not in cache:
        try:
            if text is not None and node.file_index == 0 and not os.path.isfile(path):
                cache[path] = text.encode()
            else:
                with open(path, "rb") as f:
                    cache[path] = f.read()
        except OSError:
            cache[path] = None
    return path, cache[path]


def _places(state, text: str | None = None) -> dict:
    """``FILE:LINE: <tag type='..' id='..' name='..'>`` of every parsed object, keyed by its
    id; objects without one get :data:`UNNAMED_ID` (the core's messages have the same form)."""
    import mitsuba as mi
    nodes = state.nodes
    names = _ref_names(nodes)
    data = {}
    places = {}
    for i, n in enumerate(nodes):
        if n.type == mi.ObjectType.Scene:
            continue
        user_id = n.props.id()
        if not user_id:
            n.props.set_id(UNNAMED_ID.format(i))
        elif user_id.startswith("_"):     # the loader's own (shape slots)
            user_id = ""
        try:
            path, buf = _source(state, n, text, data)
        except Exception:                 # a node the loader added
            continue
        line = buf[:int(n.offset)].count(b"\n") + 1 if buf is not None else None
        elem = _element(n, user_id, names.get(i))
        places[n.props.id()] = f"{path}:{line}: {elem}" if line is not None else f"{path}: {elem}"
    return places


#: Properties.Type names of parameter values (the others are nested objects)
_VALUE_KINDS = ("Bool", "Integer", "Float", "Vector", "Transform", "Color", "Spectrum", "String")


def _judge_parameters(state, integrator: str, text: str | None) -> None:
    """A parameter its plugin does not take is a :class:`links1.errors.SceneError` naming the
    property's FILE:LINE, the element and the property, as the core's reader names it: links1's
    plugins by their table (:func:`links1.scene.params.unknown_in`), an integrator that
    ``links1_whitted`` replaces by Mitsuba's table (Mitsuba never sees it). Mitsuba judges its
    other plugins itself when it instantiates them."""
    from links1.errors import SceneError
    from links1.scene.properties import refused_parameter
    from links1.scene.params import is_links1
    names, data = None, {}
    for i, node in enumerate(state.nodes):
        plugin = node.props.plugin_name()
        tag = _TAGS.get(node.type.name, node.type.name.lower())
        if not (is_links1(plugin) or (tag == "integrator" and integrator != "scene")):
            continue
        given = [k for k in node.props.keys() if not k.startswith("_") and node.props.type(k).name in _VALUE_KINDS]
        found = refused_parameter(tag, plugin, given)
        if found is None:
            continue
        name, message = found
        names = _ref_names(state.nodes) if names is None else names
        path, buf = _source(state, node, text, data)
        elem = _element(node, node.props.id(), names.get(i))
        at = re.compile(rb"<(\w+)\b[^>]*\bname\s*=\s*[\"']" + re.escape(name.encode()) + rb"[\"']")
        m = at.search(buf or b"", int(node.offset))
        if m is None:
            raise SceneError(message, path, None, f"{elem} <{name}>")
        line = buf[:m.start()].count(b"\n") + 1
        raise SceneError(message, path, line, f"{elem} <{m.group(1).decode()} name='{name}'>")


def _unused_parameters(exc, source) -> Exception:
    """Mitsuba's "Found unused parameters: - $res=64" (no file) as the core's one line."""
    from links1.errors import SceneError
    text = str(exc)
    if "Found unused parameters" not in text:
        return exc
    given = [ln.strip()[2:].lstrip("$") for ln in text.splitlines() if ln.strip().startswith("- $")]
    what = ", ".join(f"-D {g}" for g in given) or "parameters"
    names = ", ".join(f"${g.split('=')[0]}" for g in given)
    hint = ""
    if any(g in ("integrator=links1", "integrator=scene") for g in given):   # meant as links1's own option
        hint = "; links1's own choice of integrator is the keyword links1_integrator="
    return SceneError(f"unused parameter{'s' if len(given) > 1 else ''} {what}: the scene has no "
                      f"{names} (Mitsuba refuses unused parameters){hint}", source, 1, "<scene>")


def _load(parse, source, integrator, base_dir, variant, params, filename=None):
    import mitsuba as mi
    register(variant)
    config = mi.parser.ParserConfig(mi.variant())
    config.merge_meshes = False
    config.merge_equivalent = False
    fr = mi.file_resolver()
    saved = mi.FileResolver(fr)
    try:
        if base_dir:
            fr.prepend(base_dir)
        try:
            state = parse(config, source, **{k: str(v) for k, v in params.items()})
        except RuntimeError as exc:
            raise _unused_parameters(exc, filename or "<string>") from None
        _judge_parameters(state, integrator, None if filename else source)
        integ, specs, slot_of_id, names = _prepare_state(state, config, integrator, base_dir)
        places = _places(state, None if filename else source)
        mi.parser.transform_all(config, state)
        _hand_places(state, places)
        mesh_files = _mesh_files(state)
        scene = mi.parser.instantiate(config, state)
    finally:
        fr.clear()
        for i in range(len(saved)):
            fr.append(saved[i])
    _settle_normals(scene, mesh_files, places)
    if integrator != "scene":
        whitted = scene.integrator()
        whitted.attach(specs, slot_of_id, names, places, list(scene.shapes()))
    return scene


def _hand_places(state, places: dict) -> None:
    """Give each object of a links1 plugin that names its place in its own messages
    (``util.PLACED_PLUGINS``) that place, ``FILE:LINE: <element>``, as a property
    (``util.PLACE_PROPERTY``) that its constructor reads (``util.place_in``)."""
    for node in state.nodes:
        where = places.get(node.props.id())
        if where and node.props.plugin_name() in PLACED_PLUGINS:
            node.props[PLACE_PROPERTY] = where


def _integrator_choice(links1_integrator: str) -> str:
    if links1_integrator not in ("links1", "scene"):
        raise ValueError(f"links1_integrator must be 'links1' or 'scene', got {links1_integrator!r}")
    return links1_integrator


def load_file(path, *, links1_integrator: str = "links1", variant: str | None = None,
              params: dict | None = None, **kwparams):
    """Load a scene file for Mitsuba with the links1 plugins.

    Every keyword but the three below is a ``$name`` substitution of the scene, as for
    ``mi.load_file``: ``load_file(path, integrator="path", max_depth=2)`` sets a scene's
    ``$integrator`` and ``$max_depth`` (what ``links1 render -D integrator=path`` does).

    Parameters
    ----------
    path : str
        Mitsuba 3 XML (links1 plugins allowed), the same files as :func:`links1.scene.loader.load_scene`.
    links1_integrator : {"links1", "scene"}
        ``"links1"`` (default): render with ``links1_whitted`` whatever the file names (its
        ``max_depth`` is kept). ``"scene"``: keep the file's integrator (links1 quadrics and
        blobs are then left out, with a warning). ``links1 render --integrator``.
    variant : str, optional
        Mitsuba variant (default: the active one, else ``llvm_ad_rgb`` / ``cuda_ad_rgb``).
    params : dict, optional
        ``$name`` substitutions whatever their names, also ``links1_integrator``, ``variant``
        or ``params`` should a scene declare those.
    **kwparams
        More ``$name`` substitutions.

    A parameter that a plugin does not take (a misspelt ``difuse``) is a
    :class:`links1.errors.SceneError` naming FILE:LINE and the element, as the core's reader
    says it (:func:`links1.scene.params.unknown_in`).
    """
    import mitsuba as mi
    choice = _integrator_choice(links1_integrator)
    path = os.fspath(path)
    if not os.path.exists(path):
        raise FileNotFoundError(path)
    return _load(lambda c, p, **kw: mi.parser.parse_file(c, p, **kw), path, choice,
                 os.path.dirname(os.path.abspath(path)), variant, {**kwparams, **(params or {})},
                 filename=path)


def load_string(xml: str, *, links1_integrator: str = "links1", variant: str | None = None,
                base_dir: str | None = None, params: dict | None = None, **kwparams):
    """:func:`load_file` for an XML string (relative file names resolve against ``base_dir``;
    a scene's own ``$base_dir`` goes through ``params``)."""
    import mitsuba as mi
    choice = _integrator_choice(links1_integrator)
    return _load(lambda c, s, **kw: mi.parser.parse_string(c, s, **kw), xml, choice,
                 base_dir or os.getcwd(), variant, {**kwparams, **(params or {})})


def whitted_of(scene):
    """The ``links1_whitted`` integrator of a loaded scene (or None)."""
    from .registered import plugin_class
    integ = scene.integrator()
    return integ if isinstance(integ, plugin_class("links1_whitted")) else None
