"""Scene fuzzer: random edits of the real scenes in ``scenes/`` and a
worker process that renders them through the CLI.

Edits (:data:`EDIT_KINDS`): a number made NaN/inf/huge/negative/zero/garbage or extreme but
in range, an element or an attribute deleted, an element duplicated or moved elsewhere, a
plugin type, a property's tag or an object's tag swapped, a reference pointed at another
id, a parameter of any known name, tag and value inserted, characters inserted, the file
cut short. Each case is rendered at 24x24, spp 1 by ``links1 render`` (``links1_app.cli.main``
in a long-lived worker process, :func:`worker_main`: importing Mitsuba and compiling kernels
costs seconds, a fresh process per case would cost them every time). The contract
(:func:`check`): exit 0 with a finite image, or exit 2 with exactly one ``links1: error:``
line; never a traceback, an ``internal error``, a signal or a hang.

Run by ``tests/stress/test_fuzz.py``; ``LINKS1_FUZZ_CASES`` (cases per renderer, default
100) and ``LINKS1_FUZZ_SEED`` set the budget and the seed.
"""
from __future__ import annotations

import contextlib
import io
import json
import os
import re
import select
import subprocess
import sys
import time
import xml.etree.ElementTree as ET

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
SCENES = os.path.join(ROOT, "scenes")
RES = 24
CASE_TIMEOUT = 180.0   # seconds: a case that takes longer is a hang (a 24x24 frame takes < 5 s)

NUMBERS = ["nan", "NaN", "inf", "-inf", "+inf", "1e300", "-1e300", "1e39", "3.5e38", "1e20",
           "-1", "-0", "0", "1e-300", "1e-45", "2147483648", "4294967296", "99999999999999999999",
           "0.5", "-7.25", "1e", "abc", "", "1,2", "0x10", "1 2 3 4",
           # plausible but extreme: inside every limit, they test the arithmetic, not the checks
           "1e14", "-1e14", "1e-14", "-1e-14", "1e29", "-1e29", "1e-30", "1e-7", "65536", "3", "1e15", "1e-15"]
TYPES = {
    "shape": ["sphere", "cylinder", "disk", "rectangle", "cube", "obj", "ply", "links1_quadric",
              "links1_blob", "links1_bicubic", "instance", "shapegroup", "serialized", "nosuch"],
    "bsdf": ["diffuse", "conductor", "dielectric", "thindielectric", "plastic", "twosided",
             "links1_phong", "roughconductor", "null", "mask", "nosuch"],
    "emitter": ["point", "spot", "directional", "area", "constant", "envmap", "links1_point",
                "links1_spot", "sunsky", "nosuch"],
    "sensor": ["perspective", "orthographic", "thinlens", "radiancemeter", "nosuch"],
    "film": ["hdrfilm", "specfilm", "nosuch"],
    "rfilter": ["box", "gaussian", "tent", "lanczos", "mitchell", "catmullrom", "nosuch"],
    "integrator": ["path", "direct", "links1_whitted", "aov", "nosuch"],
    "sampler": ["independent", "stratified", "multijitter", "nosuch"],
    "texture": ["bitmap", "checkerboard", "nosuch"],
    "spectrum": ["uniform", "srgb", "blackbody", "nosuch"],
}
PROP_TAGS = ["float", "integer", "boolean", "string", "rgb", "spectrum", "point", "vector",
             "transform", "ref", "nosuch"]
PARAM_NAMES = ["radius", "center", "p0", "p1", "to_world", "filename", "max_depth", "light_samples",
               "min_weight", "sample_count", "width", "height", "fov", "near_clip", "far_clip", "intensity",
               "irradiance", "radiance", "reflectance", "diffuse", "specular", "ambient", "exponent",
               "transmittance", "ior", "int_ior", "ext_ior", "eta", "k", "threshold", "samples", "centers",
               "kind", "clip_0", "clip_0_offset", "clip_1", "capped", "subdivisions", "control_points",
               "falloff", "L1", "L2", "direction", "position", "origin", "cutoff_angle", "beam_width",
               "crop_offset_x", "crop_offset_y", "crop_width", "crop_height", "stddev", "lobes", "B", "C",
               "flip_normals", "face_normals", "seed", "adaptive", "adaptive_depth", "aovs", "scale",
               "fov_axis", "focal_length", "solver", "diffuse_reflectance", "specular_reflectance",
               "specular_transmittance", "nonlinear", "material", "to_uv", "mesh_attributes",
               "principal_point_offset_x", "rfilter", "id", "nosuch"]
STRINGS = ["sphere", "cylinder", "exact", "paper", "none", "inverse_square", "meshes/vase.patch",
           "nosuch.obj", "", "depth,normal", "x", "diagonal", "50mm", "-5mm", "bk7", "air", "nan",
           "0 0 0 1 1", "1 2 3", "0 0 0 1 1e300", "Au", "nosuch"]
GARBAGE = ["<", "&", "&amp;", "&#0;", "&#x10FFFF;", "\x00", "\ufeff", "]]>", "<!-- ", "<?xml version='1.0'?>",
           "<!DOCTYPE scene [<!ENTITY e 'x'>]>", "<scene>", "</scene>", '"', "'", "$", "${res}", "$$",
           "\u00e9", "\ud7ff", "\t\n", "<shape>", "</shape>", "<ref id=\"white\"/>"]
_NUM = re.compile(r"[-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?")


def scene_files() -> list[str]:
    return sorted(os.path.join(SCENES, f) for f in os.listdir(SCENES) if f.endswith(".xml"))


def _elements(root):
    return [e for e in root.iter() if e is not root]


def _parents(root):
    return {c: p for p in root.iter() for c in p}


def apply_edit(text: str, edit: tuple) -> str:
    """One edit, ``(kind, i, j, k)`` with free integers picking the target (taken modulo the
    number of candidates, so any integers are valid)."""
    kind, i, j, k = edit
    if kind == "cut":
        return text[: i % max(len(text), 1)]
    if kind == "garbage":   # characters XML forbids or means something by, anywhere
        at = i % max(len(text), 1)
        return text[:at] + GARBAGE[j % len(GARBAGE)] + text[at:]
    try:
        root = ET.fromstring(text)
    except ET.ParseError:
        return text[: max(0, len(text) - 1 - i % 50)]   # already broken: cut it a little more
    els = _elements(root)
    if not els:
        return text
    parents = _parents(root)
    if kind == "number":
        spots = [(e, a, m) for e in els for a, v in e.attrib.items() if a not in ("type", "id", "name")
                 for m in _NUM.finditer(v)]
        if spots:
            e, a, m = spots[i % len(spots)]
            v = e.attrib[a]
            e.set(a, v[:m.start()] + NUMBERS[j % len(NUMBERS)] + v[m.end():])
    elif kind == "delete":
        e = els[i % len(els)]
        parents[e].remove(e)
    elif kind == "duplicate":
        e = els[i % len(els)]
        p = parents[e]
        p.insert(list(p).index(e), ET.fromstring(ET.tostring(e)))
    elif kind == "attr":
        e = els[i % len(els)]
        if e.attrib:
            del e.attrib[sorted(e.attrib)[j % len(e.attrib)]]
    elif kind == "type":
        cands = [e for e in els if e.tag in TYPES and "type" in e.attrib]
        if cands:
            e = cands[i % len(cands)]
            e.set("type", TYPES[e.tag][j % len(TYPES[e.tag])])
    elif kind == "tag":
        cands = [e for e in els if e.tag in PROP_TAGS]
        if cands:
            cands[i % len(cands)].tag = PROP_TAGS[j % len(PROP_TAGS)]
    elif kind == "objtag":   # an object becomes another kind of object (a shape an emitter, ...)
        cands = [e for e in els if e.tag in TYPES]
        if cands:
            tags = sorted(TYPES) + ["scene", "include", "default", "alias", "path", "nosuch"]
            cands[i % len(cands)].tag = tags[j % len(tags)]
    elif kind == "ref":      # a reference pointed at another id of the file (another kind of object)
        refs = [e for e in els if e.tag == "ref"]
        ids = sorted({e.get("id") for e in els if e.get("id") and e.tag != "ref"})
        if refs and ids:
            refs[i % len(refs)].set("id", ids[j % len(ids)])
        elif ids:                # or a new reference to an id, somewhere
            e = ([root] + [e for e in els if e.tag in TYPES])[i % (1 + sum(e.tag in TYPES for e in els))]
            e.append(ET.Element("ref", {"id": ids[j % len(ids)]}))
    elif kind == "value":   # a whole attribute replaced (names, ids and references too)
        e = els[i % len(els)]
        if e.attrib:
            a = sorted(e.attrib)[j % len(e.attrib)]
            e.set(a, NUMBERS[k % len(NUMBERS)] if k % 3 else ["m1", "nosuch", "$res", "", "a b"][k % 5])
    elif kind == "insert":   # a parameter (any known name, any tag, any value) added to an object
        cands = [root] + [e for e in els if e.tag in TYPES or e.tag == "scene"]
        e = cands[i % len(cands)]
        tag = PROP_TAGS[j % (len(PROP_TAGS) - 2)]
        name = PARAM_NAMES[k % len(PARAM_NAMES)]
        value = NUMBERS[(i + j + k) % len(NUMBERS)]
        if tag in ("point", "vector"):
            new = ET.Element(tag, {"name": name, "x": value, "y": "1", "z": "0"})
        elif tag == "transform":
            new = ET.Element(tag, {"name": name})
            ET.SubElement(new, ["scale", "translate", "rotate", "matrix", "lookat"][k % 5],
                          {"value": value, "x": value, "angle": value, "origin": "0 0 0", "target": value + " 0 1"})
        elif tag == "boolean":
            new = ET.Element(tag, {"name": name, "value": ["true", "false", value][k % 3]})
        elif tag == "string":
            new = ET.Element(tag, {"name": name, "value": STRINGS[(j + k) % len(STRINGS)]})
        else:
            new = ET.Element(tag, {"name": name, "value": value})
        e.insert((i // 7) % (len(e) + 1), new)
    elif kind == "move":   # an element moved under another one (a BSDF into a sensor, ...)
        e, dst = els[i % len(els)], els[j % len(els)]
        if e is not dst and e not in list(dst.iter()):
            parents[e].remove(e)
            dst.append(e)
    else:
        raise ValueError(kind)
    return ET.tostring(root, encoding="unicode")


EDIT_KINDS = ("number", "number", "number", "delete", "duplicate", "attr", "type", "tag", "objtag",
              "value", "cut", "garbage", "insert", "insert", "move", "ref")


def make_case(directory: str, name: str, scene: str, edits) -> str:
    """Write the edited scene next to links to the scenes' include/ and meshes/ folders."""
    for sub in ("include", "meshes"):
        link = os.path.join(directory, sub)
        if not os.path.lexists(link):
            os.symlink(os.path.join(SCENES, sub), link)
    with open(scene, encoding="utf-8") as f:
        text = f.read()
    for edit in edits:
        text = apply_edit(text, edit)
    path = os.path.join(directory, name)
    with open(path, "w", encoding="utf-8") as f:
        f.write(text)
    return path


def argv_for(path: str, out: str, renderer: str, extra=()) -> list[str]:
    return ["render", path, "-o", out, "--width", str(RES), "--height", str(RES), "--spp", "1",
            "--renderer", renderer, "--no-progress", *extra]


def check(rc, stderr: str, image_ok: bool | None) -> str | None:
    """The contract; None when it holds, else what broke it."""
    if rc is None:
        return "hang"
    if rc < 0 or rc > 128:
        return f"signal (exit {rc})"
    if "Traceback" in stderr or "internal error" in stderr:
        return "traceback or internal error: " + stderr.strip().splitlines()[-1][:300]
    errors = [ln for ln in stderr.splitlines() if ln.startswith("links1: error:")]
    if rc == 0:
        if errors:
            return "exit 0 with an error line"
        if not image_ok:
            return "exit 0 without a finite image"
        return None
    if rc == 2:
        if len(errors) != 1:
            return f"exit 2 with {len(errors)} error lines"
        others = [ln for ln in stderr.splitlines()
                  if ln.strip() and not ln.startswith(("links1: error:", "links1: warning:"))]
        if others:
            return f"exit 2 with other output: {others[0][:200]}"
        return None
    return f"exit {rc}: {stderr.strip()[-300:]}"


# ---------------------------------------------------------------------------- worker process
def worker_main() -> None:
    """Render cases read as JSON lines from stdin; answer one JSON line each on stdout."""
    import numpy as np

    from links1_app.cli import main
    from links1.imaging.image import read_image
    out = sys.stdout
    sys.stdout = sys.stderr          # anything printed by a case stays off the answer channel
    for line in sys.stdin:
        req = json.loads(line)
        buf = io.StringIO()
        if os.path.exists(req["out"]):
            os.remove(req["out"])
        with contextlib.redirect_stderr(buf):
            try:
                rc = main(req["argv"])
            except SystemExit as e:           # argparse
                rc = e.code if isinstance(e.code, int) else 2
            except BaseException as e:  # noqa: BLE001 - reported as a broken contract
                import traceback
                rc = 1
                buf.write("Traceback (escaped main): " + "".join(traceback.format_exception(e))[-500:])
        ok = None
        if rc == 0:
            try:
                ok = bool(np.all(np.isfinite(read_image(req["out"]))))
            except Exception as e:  # noqa: BLE001
                buf.write(f"cannot read the output: {e}\n")
                ok = False
        out.write(json.dumps({"rc": rc, "stderr": buf.getvalue(), "image_ok": ok}) + "\n")
        out.flush()


class Worker:
    """A worker subprocess, restarted after a crash or a hang."""

    #: the worker's command (tests of this harness substitute one that crashes or hangs)
    COMMAND = [sys.executable, "-c", "from tests.stress.fuzz import worker_main; worker_main()"]

    def __init__(self, env=None, command=None):
        self.command = list(command or self.COMMAND)
        self.env = dict(os.environ if env is None else env)
        self.env["PYTHONPATH"] = os.pathsep.join([ROOT, self.env.get("PYTHONPATH", "")])
        self.env.setdefault("PYTHONFAULTHANDLER", "")
        self.proc = None

    def _start(self):
        self.proc = subprocess.Popen(self.command,
                                     stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=subprocess.DEVNULL,
                                     text=True, cwd=ROOT, env=self.env)

    def run(self, argv, out: str, timeout: float = CASE_TIMEOUT) -> tuple:
        """``(rc, stderr, image_ok)``; rc None on a hang, negative on a signal."""
        if self.proc is None or self.proc.poll() is not None:
            self._start()
        self.proc.stdin.write(json.dumps({"argv": argv, "out": out}) + "\n")
        self.proc.stdin.flush()
        end = time.monotonic() + timeout
        while True:
            left = end - time.monotonic()
            if left <= 0:
                self.close(kill=True)
                return None, "", None
            r, _, _ = select.select([self.proc.stdout], [], [], min(left, 1.0))
            if r:
                line = self.proc.stdout.readline()
                if not line:                       # the worker died: a signal
                    rc = self.proc.wait()
                    self.proc = None
                    return (rc if rc < 0 else -abs(rc or 1)), "", None
                d = json.loads(line)
                return d["rc"], d["stderr"], d["image_ok"]
            if self.proc.poll() is not None:
                rc = self.proc.returncode
                self.proc = None
                return (rc if rc < 0 else -abs(rc or 1)), "", None

    def close(self, kill=False):
        if self.proc is None:
            return
        if kill:
            self.proc.kill()
        else:
            self.proc.stdin.close()
        try:
            self.proc.wait(timeout=30)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            self.proc.wait()
        self.proc = None
