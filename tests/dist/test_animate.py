"""``links1 animate``: sequences over the nodes, per-frame values, resume, frame-coherent plans."""
from __future__ import annotations

import math
import os
import sys

import numpy as np
import pytest

from links1.errors import UsageError
from links1.imaging.image import read_image
from links1_app.animate import animate, make_backend, output_path
from links1_app.cli import main
from links1_app.expressions import Expression, frame_values, parse_frames
from links1_app.renderers import make_renderer

from .conftest import MANY

ORBIT = ("eye", "14*sin(radians(30*f)), 9, 14*cos(radians(30*f))")
OPTS = dict(width=32, height=32, spp=1)


def single(frame, aovs=("cost",)):
    """The single-process render of one orbit frame, loaded from scratch with that frame's values."""
    v = frame_values([ORBIT], [frame], 24.0)[0]
    return make_renderer("core", MANY, params=v, aovs=aovs, **OPTS).render()


@pytest.fixture(scope="module")
def refs():
    return {f: single(f) for f in range(3)}


# ---------------------------------------------------------------------- expressions
def test_expression_values_are_the_arithmetic():
    e = Expression("eye", "14*sin(radians(30*f)), 9, 2**3 - t")
    assert e.varies
    assert e.value(1, 0.5) == f"{14 * math.sin(math.radians(30)) !r}, 9, 7.5"
    assert Expression("res", "32").value(7, 1.0) == "32"
    assert Expression("kind", "sphere").value(3, 0.1) == "sphere"     # a word: the scene's string
    assert frame_values([("a", "f*0.5")], [0, 1, 2], 2.0) == [{"a": "0"}, {"a": "0.5"}, {"a": "1"}]


@pytest.mark.parametrize("text", ["__import__('os').system('true')", "f.real", "open(f)", "sin(f, f)",
                                  "[f][0]", "2**(100000+f)", "(lambda: 1)()", "log(f)"])
def test_expression_refuses_what_is_not_arithmetic(text):
    with pytest.raises(UsageError, match="-D x="):
        frame_values([("x", text)], [0, 1], 24.0)


def test_frames_option():
    assert parse_frames("0:4") == [0, 1, 2, 3]
    assert parse_frames("3") == [0, 1, 2]
    assert parse_frames("2:9:3") == [2, 5, 8]
    for bad in ("a:b", "4:2", "0:4:0", "-2:1"):
        with pytest.raises(UsageError, match="--frames"):
            parse_frames(bad)
    assert output_path("o/f_%03d.exr", 7) == "o/f_007.exr" and output_path("o/f.png", 7) == "o/f_0007.png"


def test_bad_expression_is_one_line_and_exit_2(tmp_path, capsys):
    out = tmp_path / "f_%02d.png"
    code = main(["animate", MANY, "-o", str(out), "--frames", "2", "--renderer", "core",
                 "-D", "eye=exec('x'), 9, 14", "--no-progress"])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2
    assert len(err) == 1 and err[0].startswith("links1: error: -D eye=") and "exec" in err[0]
    assert not list(tmp_path.iterdir())


# ---------------------------------------------------------------------- bits over the nodes
def check_frames(res, refs, frames=(0, 1, 2)):
    assert sorted(res.images) == list(frames)
    for f in frames:
        assert np.array_equal(res.images[f], refs[f]), f"frame {f} differs from its single-process render"


@pytest.mark.slow
def test_in_process_frames_equal_single_renders(refs):
    for units in ("frames", "partition"):
        res = animate(MANY, frames=[0, 1, 2], defines=[ORBIT], units=units, keep_images=True, aovs=("cost",),
                      progress=False, **OPTS)
        check_frames(res, refs)


@pytest.mark.slow
@pytest.mark.parametrize("nodes, choices", [
    (2, (("frames", "eq41"), ("both", "eq41"), ("partition", "eq41"), ("partition", "previous"))),
    (3, (("frames", "eq41"), ("both", "previous"), ("partition", "previous"))),
])
def test_pool_every_unit_choice_is_bit_identical(refs, nodes, choices):
    be = make_backend(workers=nodes)
    try:
        for units, plan_from in choices:
            res = animate(MANY, frames=[0, 1, 2], defines=[ORBIT], units=units, plan_from=plan_from, backend=be,
                          keep_images=True, aovs=("cost",), progress=False, tiles_per_node=4, **OPTS)
            assert res.n_nodes == nodes
            check_frames(res, refs)
    finally:
        be.close()


@pytest.mark.slow
def test_dask_local_cluster_is_bit_identical(refs):
    pytest.importorskip("distributed")
    be = make_backend(dask_local=2)
    try:
        for units, partition in (("frames", "subscreen"), ("both", "subscreen"), ("partition", "subscreen"),
                                 ("partition", "dynamic")):
            res = animate(MANY, frames=[0, 1, 2], defines=[ORBIT], units=units, partition=partition, backend=be,
                          keep_images=True, aovs=("cost",), progress=False, tiles_per_node=4, **OPTS)
            assert all(fr.get("imbalance_ray_tests", 1.0) >= 1.0 for fr in res.frames)
            check_frames(res, refs)
    finally:
        be.close()


# ---------------------------------------------------------------------- files and resume
@pytest.mark.slow
def test_cli_writes_frames_and_resumes_at_the_missing_ones(tmp_path, capsys, refs):
    pattern = str(tmp_path / "f_%02d.exr")
    args = ["animate", MANY, "-o", pattern, "--frames", "3", "--renderer", "core", "--width", "32",
            "--height", "32", "--spp", "1", "-D", f"{ORBIT[0]}={ORBIT[1]}", "--no-progress", "--checkpoint"]
    assert main(args) == 0
    paths = [tmp_path / f"f_{f:02d}.exr" for f in range(3)]
    for f, p in enumerate(paths):
        img = read_image(str(p))
        assert np.array_equal(img[..., :3], refs[f][..., :3].astype(np.float32))
    os.remove(paths[1])
    stamp = {p: os.stat(p).st_mtime_ns for p in (paths[0], paths[2])}
    capsys.readouterr()
    assert main(args) == 0
    err = capsys.readouterr().err
    assert "2 of 3 frames were on disk already" in err and "wrote 1 frames" in err
    assert paths[1].exists() and all(os.stat(p).st_mtime_ns == t for p, t in stamp.items())


# ---------------------------------------------------------------------- frame-coherent plans
@pytest.mark.slow
def test_previous_frame_plan_is_no_worse_than_eq41_where_the_load_moves():
    """An orbit around many.xml moves the load across the screen: the previous frame's measured
    ray tests predict the next frame's split at least as well as eq. 4.1's object rectangles
    (imbalance counted in exact ray tests, the cost AOV: no timing)."""
    frames = list(range(6))
    orbit = [("eye", "14*sin(radians(6*f)), 9, 14*cos(radians(6*f))")]
    got = {}
    be = make_backend(workers=2)
    try:
        for plan_from in ("eq41", "previous"):
            res = animate(MANY, frames=frames, defines=orbit, units="partition", plan_from=plan_from, backend=be,
                          progress=False, tiles_per_node=8, width=48, height=48, spp=1)
            got[plan_from] = [fr["imbalance_ray_tests"] for fr in res.frames[1:]]
            if plan_from == "previous":
                assert [fr["plan_from"] for fr in res.frames] == ["eq41"] + ["previous"] * 5
    finally:
        be.close()
    assert np.mean(got["previous"]) <= np.mean(got["eq41"])


# ---------------------------------------------------------------------- experiment and simulation
def test_simulated_throughput_of_whole_frames_is_list_scheduling():
    """Equal frames of T seconds over N nodes, one at a time, no overheads: ceil(F / N) x T."""
    from types import SimpleNamespace
    from links1_app.partition.sequence_report import best_choices, simulate_sequence
    T, F = 0.5, 10
    one = SimpleNamespace(frames=[{"frame": f, "render_s": T} for f in range(F)], setup_s=[])
    costs = {f: np.ones((8, 8)) for f in range(F)}
    rows = simulate_sequence(one, costs, {}, [1, 4, 16], tiles_per_node=2)
    thr = {r["nodes"]: r for r in rows if r["way"] == "frames"}
    for n in (1, 4, 16):
        assert thr[n]["makespan_s"] == pytest.approx(math.ceil(F / n) * T)
        assert thr[n]["efficiency"] == pytest.approx(F * T / (n * math.ceil(F / n) * T))
    lat = {r["nodes"]: r for r in rows if r["way"] == "previous"}
    assert lat[4]["makespan_s"] == pytest.approx(T / 4)     # uniform cost, 8 tiles in 4 equal groups
    best = best_choices(rows)
    # without overheads, splitting every frame over 16 nodes beats 10 whole frames on 10 of them
    assert best[16]["throughput"]["way"] in ("previous", "both")
    assert best[16]["throughput"]["frames_per_s"] == pytest.approx(F / (F * T / 16))
    assert best[1]["throughput"]["efficiency"] == pytest.approx(1.0)


@pytest.mark.slow
def test_report_and_plot(tmp_path, capsys):
    pytest.importorskip("matplotlib")
    import json
    rep, png = tmp_path / "r.json", tmp_path / "r.png"
    code = main(["animate", MANY, "-o", str(tmp_path / "f_%02d.png"), "--frames", "3", "--renderer", "core",
                 "--width", "32", "--height", "32", "--spp", "1", "-D", f"{ORBIT[0]}={ORBIT[1]}", "--no-progress",
                 "--workers", "2", "--tiles-per-node", "4", "--ways", "previous,frames", "--report", str(rep),
                 "--plot", str(png), "--simulate", "4,64"])
    assert code == 0
    r = json.loads(rep.read_text())
    assert [s["way"] for s in r["ways"]] == ["previous", "frames"] and r["nodes"] == 2
    prev = r["ways"][0]
    assert [fr["plan_from"] for fr in prev["frames"]] == ["eq41", "previous", "previous"]
    assert all(fr["imbalance_ray_tests"] >= 1.0 for fr in prev["frames"])
    assert sorted(r["simulation"]["best"]) == ["4", "64"]
    assert png.stat().st_size > 0 and len(list(tmp_path.glob("f_*.png"))) == 3


def test_reproject_follows_the_camera():
    """A point at the centre of one view lands at the centre of a view that turned to look at it
    from the side; misses stay in place; a still camera changes nothing; the total is kept."""
    from links1.maths.transform import look_at
    from links1.sensor.camera import Camera
    from links1_app.partition.sequence import reproject
    w = h = 9
    cam0 = Camera(to_world=look_at([0, 0, 5], [0, 0, 0], [0, 1, 0]), fov_x=40, width=w, height=h)
    cam1 = Camera(to_world=look_at([5, 0, 0], [0, 0, 0], [0, 1, 0]), fov_x=40, width=w, height=h)
    cost, depth = np.zeros((h, w)), np.full((h, w), np.inf)
    cost[4, 4], depth[4, 4] = 100.0, 5.0      # the origin, seen through the centre pixel
    cost[0, 0] = 3.0                           # a miss (background)
    assert reproject(cost, depth, cam0, cam0) is cost
    got = reproject(cost, depth, cam0, cam1)
    assert got[4, 4] == 100.0 and got[0, 0] == 3.0 and got.sum() == pytest.approx(103.0)


# ---------------------------------------------------------------------- the Python API, faults, Ctrl-C
def orbit_camera(scene, f, t):
    """A per-frame update of the core's loaded scene (what ``animate(update=...)`` calls on every
    node): the camera circles the origin; with LINKS1_TEST_DIE_AT set, the first node to reach
    frame 2 dies (os._exit), once."""
    import dataclasses
    from links1.maths.transform import look_at
    marker = os.environ.get("LINKS1_TEST_DIE_AT")
    if marker and f == 2:
        try:
            os.close(os.open(marker, os.O_CREAT | os.O_EXCL))   # one node wins, even two at once
        except FileExistsError:
            pass
        else:
            os._exit(3)
    if os.environ.get("LINKS1_TEST_SET_LOG"):      # the frames a node set its scene to, one line each
        with open(os.environ["LINKS1_TEST_SET_LOG"], "a") as log:
            log.write(f"{f}\n")
    a = math.radians(30 * f)
    scene.camera = dataclasses.replace(scene.camera, to_world=look_at([14 * math.sin(a), 9, 14 * math.cos(a)],
                                                                      [0, 0, 0], [0, 1, 0]))


@pytest.mark.slow
def test_update_function_and_a_worker_killed_mid_sequence(tmp_path, monkeypatch):
    """The Python API's update function moves the loaded scene per frame (no re-read); a node that
    dies at frame 2 costs only its units: they are redone, and every frame equals the in-process one.
    In whole frames, the surviving nodes set up frames 1, 2 and 3 once each: no finished frame was
    rendered again."""
    ref = animate(MANY, frames=[0, 1, 2, 3], update=orbit_camera, units="frames", keep_images=True,
                  progress=False, **OPTS)
    assert not np.array_equal(ref.images[0], ref.images[1])     # the update moved the camera
    marker = tmp_path / "died"
    monkeypatch.setenv("LINKS1_TEST_DIE_AT", str(marker))
    be = make_backend(workers=2)
    logged = []
    try:
        for units in ("frames", "partition"):
            if marker.exists():
                marker.unlink()
            set_log = tmp_path / f"set-{units}.txt"
            monkeypatch.setenv("LINKS1_TEST_SET_LOG", str(set_log))
            res = animate(MANY, frames=[0, 1, 2, 3], update=orbit_camera, units=units, backend=be, keep_images=True,
                          progress=False, tiles_per_node=4, log=logged.append, **OPTS)
            assert marker.exists() and len(res.faults) == 1, units
            if units == "frames":     # frame 0: every node's scene is loaded at it
                assert sorted(int(v) for v in set_log.read_text().split() if v != "0") == [1, 2, 3]
            for f in range(4):
                assert np.array_equal(res.images[f], ref.images[f]), (units, f)
    finally:
        be.close()
    assert any("died" in m for m in logged)


def test_ctrl_c_leaves_every_finished_frame_whole(tmp_path):
    import signal
    import subprocess
    import sys
    import time
    from tests.interrupts import _MAIN, ROOT, _kill_session, processes_left
    r, w = os.pipe()
    args = ["animate", MANY, "-o", str(tmp_path / "f_%02d.exr"), "--frames", "40", "--renderer", "core",
            "--width", "32", "--height", "32", "--spp", "1", "-D", f"{ORBIT[0]}={ORBIT[1]}", "--no-progress",
            "--workers", "2", "--units", "frames", "--aov", "cost"]
    p = subprocess.Popen([sys.executable, "-c", _MAIN, str(w), *args], cwd=ROOT, pass_fds=(w,),
                         start_new_session=True, stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    os.close(w)
    try:
        os.read(r, 1)        # links1 is imported: from here Ctrl-C is links1's to handle
    finally:
        os.close(r)
    try:
        deadline = time.monotonic() + 120
        while len(list(tmp_path.glob("f_*.exr"))) < 2 and p.poll() is None and time.monotonic() < deadline:
            time.sleep(0.05)
        assert p.poll() is None, "the sequence ended before the interrupt; make it longer"
        os.killpg(p.pid, signal.SIGINT)
        _, err = p.communicate(timeout=60)
        assert p.returncode == 130 and err.decode().strip().splitlines()[-1] == "links1: interrupted"
        assert not processes_left(p.pid)
    finally:
        if p.poll() is None:
            p.kill()
        _kill_session(p.pid)
    names = sorted(x.name for x in tmp_path.iterdir())
    assert 2 <= len(names) < 40 and all(n.startswith("f_") and n.endswith(".exr") and len(n) == 8 for n in names)
    for n in names:       # whole: each reads back as its frame's single-process render
        f = int(n[2:4])
        assert np.array_equal(read_image(str(tmp_path / n)), single(f).astype(np.float32)), n


@pytest.mark.slow
def test_mitsuba_frames_updated_in_place_equal_fresh_loads():
    """The plugin's loaded scene updated per frame (mi.traverse / params.update(): its kernels
    kept) renders each frame as a fresh load of the file with that frame's values does."""
    pytest.importorskip("mitsuba")
    frames = [0, 1]
    res = animate(MANY, frames=frames, defines=[ORBIT], renderer="mitsuba", units="frames", keep_images=True,
                  progress=False, aovs=("cost",), **OPTS)
    for f in frames:
        v = frame_values([ORBIT], [f], 24.0)[0]
        ref = make_renderer("mitsuba", MANY, params=v, aovs=("cost",), **OPTS).render()
        assert np.array_equal(res.images[f], ref), f


def test_video_needs_its_extra(tmp_path, capsys, monkeypatch):
    monkeypatch.setitem(sys.modules, "imageio_ffmpeg", None)      # import fails as if not installed
    code = main(["animate", MANY, "-o", str(tmp_path / "f.png"), "--frames", "2", "--renderer", "core",
                 "--video", str(tmp_path / "v.mp4"), "--no-progress"])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(err) == 1 and "links1[video]" in err[0] and not list(tmp_path.iterdir())


def test_video_holds_the_frames_in_order(tmp_path):
    """--video encodes the written frames at --fps: decoded, the video has one picture a frame,
    the film's size, and its k-th picture is far closer to frame k's sRGB image than to any other (the orbit's frames
    differ, so an order or a count mistake shows)."""
    ffmpeg = pytest.importorskip("imageio_ffmpeg")
    from links1.imaging.image import linear_to_srgb
    video = tmp_path / "orbit.mp4"
    code = main(["animate", MANY, "-o", str(tmp_path / "f_%02d.exr"), "--frames", "4", "--renderer", "core",
                 "--width", "32", "--height", "32", "--spp", "1", "-D", f"{ORBIT[0]}=14*sin(radians(60*f)), 9, "
                 "14*cos(radians(60*f))", "--fps", "12", "--video", str(video), "--no-progress"])
    assert code == 0 and video.stat().st_size > 0
    frames = [np.clip(linear_to_srgb(read_image(str(tmp_path / f"f_{f:02d}.exr"))[..., :3]), 0, 1) * 255
              for f in range(4)]
    gen = ffmpeg.read_frames(str(video))
    meta = next(gen)
    assert tuple(meta["size"]) == (32, 32) and abs(meta["fps"] - 12) < 1e-6
    pics = [np.frombuffer(b, np.uint8).reshape(32, 32, 3).astype(np.float64) for b in gen]
    assert len(pics) == 4
    for k, pic in enumerate(pics):
        err = [np.mean(np.abs(pic - f)) for f in frames]
        others = min(e for j, e in enumerate(err) if j != k)
        assert err[k] < 0.5 * others and err[k] < 20.0, (k, err)     # lossy (4:2:0 chroma at 32²), but its own frame


def test_sequence_plans_cover_their_frames_once():
    """Whole frames, whole frames then split ones, and a frame's plan moved to its rows each cover
    exactly their frames' rows of the tall film, once."""
    from links1.partition.strategies import make_plan
    from links1_app.partition.sequence import frame_units_plan, shifted
    W, H, F = 20, 12, 5
    for split in (0, 2):
        plan = frame_units_plan(W, H, [1, 2, 4], 2, F, split_last=split, tiles_per_node=3)
        cover = plan.coverage()
        want = np.zeros((H * F, W), dtype=np.int64)
        for k in (1, 2, 4):
            want[k * H:(k + 1) * H] = 1
        assert np.array_equal(cover, want)
        assert len(plan.units) == 3 - split + split * len(make_plan("grid", W, H, 2, tiles_per_node=3).units)
    tall = shifted(make_plan("subscreen", W, H, 2, tiles_per_node=4), 3, H, F)
    assert tall.height == H * F and tall.coverage()[3 * H:4 * H].min() == 1 and tall.coverage().sum() == W * H


def test_a_node_loads_the_scene_once_and_updates_it():
    """A node's sequence renderer keeps its one loaded core scene over the frames: the file is
    read once, each frame's values are set in place, and each frame's window equals a fresh load."""
    from links1_app.partition.sequence import SequenceRenderer
    values = frame_values([ORBIT], [0, 1, 2], 24.0)
    r = SequenceRenderer(MANY, frames=values, aovs=("cost",), **OPTS)
    inner, scene = r.inner, r.inner.scene
    got = r.render_batch([(0, 32 * k, 32, 32) for k in (2, 0, 1)])
    assert r.inner is inner and inner.scene is scene and inner.source.sources.reads == 2   # many.xml, camera.xml
    assert len(r.setup_s) == 3
    for k, img in zip((2, 0, 1), got):
        assert np.array_equal(img, single(k)), k


def test_orbit_example_scene_is_the_eye_orbit(refs):
    """scenes/sequences/orbit.xml at -D angle='30*f' is many.xml seen from eye (14 sin a, 9, 14 cos a),
    a = 30 f degrees: the same camera (to rounding) and the same frames."""
    orbit = os.path.join(os.path.dirname(MANY), "sequences", "orbit.xml")
    res = animate(orbit, frames=[0, 1, 2], defines=[("angle", "30*f")], units="frames", keep_images=True,
                  aovs=("cost",), progress=False, **OPTS)
    for f in range(3):
        a = math.radians(30 * f)
        cam = make_renderer("core", orbit, params={"angle": str(30 * f)}, **OPTS).scene.camera
        want = make_renderer("core", MANY, params=frame_values([ORBIT], [f], 24.0)[0], **OPTS).scene.camera
        assert np.allclose(cam.to_world, want.to_world, rtol=0, atol=1e-12) and cam.fov_x == want.fov_x
        assert np.allclose(cam.to_world[:3, 3], [14 * math.sin(a), 9, 14 * math.cos(a)], rtol=0, atol=1e-12)
        assert np.allclose(res.images[f], refs[f], rtol=0, atol=1e-9), f


def mitsuba_orbit(params, f, t):
    """A per-frame update of the plugin's loaded scene (``params``: its ``mi.traverse``): the
    sensor's ``to_world`` at the orbit's eye for frame ``f`` (the key found by the sensor's x_fov)."""
    import mitsuba as mi
    sensor = next(k for k in params.keys() if k.endswith(".x_fov"))[:-len("x_fov")]
    a = math.radians(30 * f)
    # in double, then float32, as Mitsuba's XML reader makes a <lookat>
    m = mi.ScalarTransform4d().look_at(origin=[14 * math.sin(a), 9, 14 * math.cos(a)], target=[0, 0, 0], up=[0, 1, 0])
    params[sensor + "to_world"] = mi.ScalarTransform4f(np.asarray(m.matrix, dtype=np.float32))


@pytest.mark.slow
def test_mitsuba_update_function_moves_the_loaded_scene():
    """animate(update=...) with the plugin: the function changes mi.traverse(scene), animate calls
    params.update() and the integrator re-prepares; each frame equals a fresh load of the file at
    that frame's eye."""
    pytest.importorskip("mitsuba")
    frames = [0, 1]
    res = animate(MANY, frames=frames, update=mitsuba_orbit, renderer="mitsuba", units="frames", keep_images=True,
                  progress=False, **OPTS)
    for f in frames:
        v = frame_values([ORBIT], [f], 24.0)[0]
        ref = make_renderer("mitsuba", MANY, params=v, **OPTS).render()
        assert np.array_equal(res.images[f], ref), f
