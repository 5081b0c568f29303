"""A scene file read once and built once, then given other ``$name`` values in place.

What a sequence of frames needs (``links1 animate``: each node loads the scene once): frame
``k``'s values rebuild only the top-level elements (a shape, a sensor, an emitter) whose
parameters changed (:attr:`links1.scene.xmlparse.Node.uses`: the ``$name`` parameters the
element, its nested elements and the objects it references take); the others are the objects
built before. The file and its includes are parsed again from memory with the new values (the
same checks as a load: an undefined or unused parameter is the same error), never read from
the disk again; the :class:`~links1.scene.scene.Scene` object is kept, and with it what was built
from its shapes and lights (the BVH, the integrator's plan: content-keyed, so a camera move keeps
them and a moved shape rebuilds them). A value that changes the file's structure (an
``<include>`` filename, a ``<path>``) rebuilds every element. The scene after :meth:`SceneFile.update`
equals a fresh :func:`~links1.scene.loader.load_scene` with the same values.
"""
from __future__ import annotations

import os

from .loader import build_scene
from .scene import Scene
from .xmlparse import Sources, _param_str, parse_file


class SceneFile:
    """``SceneFile(path, **params)``: the file's :class:`Scene` (:attr:`scene`) with ``params``;
    :meth:`update` gives it other values."""

    def __init__(self, path, /, **params):
        self.path = os.fspath(path)
        self.sources = Sources()
        self.params = {k: _param_str(v) for k, v in params.items()}
        self.root = parse_file(self.path, self.params, self.sources)
        self.kept: dict = {}
        self.scene: Scene = build_scene(self.root, self.path, self.kept)
        #: per update, the top-level elements built again (indices into the root's children)
        self.rebuilt: list = []

    def changed(self, params: dict) -> set:
        """The parameter names whose value ``params`` changes (given, no longer given, or other)."""
        new = {k: _param_str(v) for k, v in params.items()}
        return {k for k in set(new) | set(self.params) if new.get(k) != self.params.get(k)}

    def update(self, /, **params) -> set:
        """Give the scene the values ``params`` (all of them, as :func:`load_scene` takes them:
        a parameter not given takes its ``<default>``); returns the names that changed. On an
        error (the values make a bad scene) the scene is left as it was."""
        changed = self.changed(params)
        if not changed:
            self.rebuilt = []
            return changed
        new = {k: _param_str(v) for k, v in params.items()}
        root = parse_file(self.path, new, self.sources)
        same = _same_structure(self.root, root) and not (changed & (self.root.uses | root.uses))
        kept = {i: v for i, v in self.kept.items() if same and not (changed & root.children[i][1].uses)}
        rebuilt = sorted(set(self.kept) - set(kept))
        fresh = build_scene(root, self.path, kept)
        self.rebuilt = rebuilt
        self.scene.take(fresh)
        self.root, self.kept, self.params = root, kept, new
        return changed


def _same_structure(a, b) -> bool:
    """The two parses have the same top-level elements (kind, type, id, place), in order."""
    def shape(root):
        return [(n.tag, n.type, n.id, n.file, n.line) for _, n in root.children]
    return shape(a) == shape(b)
