"""A ray-tree probe run on some cases (``--only``) updates those cases of its results file and
keeps the others, each naming the run that measured it (compare.ray_tree_parts.merge_cases)."""
from compare.ray_tree_parts import measured_note, merge_cases


def _case(cid, ms, measured=None):
    c = dict(id=cid, spp=16, rows=[dict(part="ray-tree kernel", ms=ms)])
    if measured:
        c["measured"] = measured
    return c


OLD = dict(machine=dict(git_commit="aaaaaaa", load_average_at_start=[3.5, 4.0, 4.1]),
           command="python -m compare.ray_tree_parts",
           cases=[_case("teapot", 1.0), _case("cbox_point", 2.0), _case("delta_bsdfs", 3.0)])
RUN = dict(commit="bbbbbbb", load=[0.8, 1.0, 1.2], command="python -m compare.ray_tree_parts --only cbox_point")


def test_only_run_replaces_its_cases_and_keeps_the_others():
    merged = merge_cases(OLD, [_case("cbox_point", 9.0, RUN), _case("new_scene", 5.0, RUN)])
    assert [c["id"] for c in merged] == ["teapot", "cbox_point", "delta_bsdfs", "new_scene"]
    assert [c["rows"][0]["ms"] for c in merged] == [1.0, 9.0, 3.0, 5.0]
    assert merged[1]["measured"] == RUN
    for c in (merged[0], merged[2]):   # kept: the old file's run
        assert c["measured"] == dict(commit="aaaaaaa", load=[3.5, 4.0, 4.1],
                                     command="python -m compare.ray_tree_parts")
    assert "measured" not in OLD["cases"][0]   # the old payload is left as it was
    assert "commit bbbbbbb" in measured_note(merged[1]) and "--only cbox_point" in measured_note(merged[1])
    assert "commit aaaaaaa" in measured_note(merged[0])


def test_no_results_file_yet():
    merged = merge_cases(None, [_case("teapot", 1.0, RUN)])
    assert [c["id"] for c in merged] == ["teapot"] and merged[0]["measured"] == RUN
