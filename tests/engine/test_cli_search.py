"""`skelasm search`: the ranked fits as text and JSON; bad options as one line."""

import json

import pytest
from search_pairs import through_round

from app.cli import main


@pytest.fixture(scope="module")
def scene(tmp_path_factory):
    path, _ = through_round(tmp_path_factory.mktemp("cli_through"))
    return path


def test_json_gives_the_ranked_fits_with_their_joints(scene, tmp_path, capsys):
    out = tmp_path / "fits.json"
    status = main(["search", str(scene), "--rotations", "72", "--scan-modes", "12", "--top",
                   "2", "--json", "-o", str(out)])
    captured = capsys.readouterr()
    assert status == 0
    result = json.loads(captured.out)
    assert result == json.loads(out.read_text()) | {
        "seconds_with_preparation": result["seconds_with_preparation"]}
    assert result["rotations"] == 72 and result["angle_degrees"] == 60
    assert "left" in captured.err  # progress with the time left, on stderr
    best = result["fits"][0]
    assert best["rank"] == 1 and len(best["pose"]) == 6 and best["cluster_size"] >= 1
    assert best["joint"]["kind"] == "cylindrical"
    (axis,) = best["joint"]["free_translations"]
    assert abs(axis[2]) > 0.97
    assert abs(best["pose"][0]) < 0.5 and abs(best["pose"][1]) < 0.5
    # how the parts meet there, on their meshes: touching, not through the bore's wall
    assert best["contact"]["touching"] > 0.05 and best["contact"]["inside"] < 0.05


@pytest.mark.parametrize("argv, message", [
    (["--rotations", "10", "--angle", "30"], "not allowed with"),
    (["--angle", "0.1"], "finer than the deepest"),
    (["--workers", "2", "--scheduler", "tcp://127.0.0.1:9"], "give one"),
    (["--top", "0"], "from 1 to 100"),
])
def test_bad_options_are_one_line(scene, capsys, argv, message):
    with pytest.raises(SystemExit) if "not allowed" in message or "from 1" in message else \
            _no_raise():
        status = main(["search", str(scene), *argv])
        assert status == 2
    err = capsys.readouterr().err
    assert message in err and "Traceback" not in err


class _no_raise:
    def __enter__(self):
        return self

    def __exit__(self, *exc):
        return False


def test_a_scene_without_its_assembled_pose_is_searched_and_elsewhere_refused(scene, tmp_path,
                                                                            capsys):
    from engine.scene import load_scene

    bare = tmp_path / "bare"
    bare.mkdir()
    for name in ("block.stl", "peg.stl"):
        (bare / name).write_bytes((scene.parent / name).read_bytes())
    text = scene.read_text().replace("assembled_pose = [0, 0, 0, 0, 0, 0]\n", "")
    (bare / "scene.toml").write_text(text)
    assert not load_scene(bare / "scene.toml").assembled_known
    assert load_scene(scene).assembled_known
    assert main(["search", str(bare / "scene.toml"), "--rotations", "72", "--scan-modes",
                 "12", "--top", "1", "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["fits"][0]["joint"]["kind"] == "cylindrical"
    for command in (["evaluate"], ["landscape", "-o", str(tmp_path / "l.png")]):
        assert main([command[0], str(bare / "scene.toml"), *command[1:]]) == 2
        err = capsys.readouterr().err
        assert "skelasm search" in err and "assembled_pose" in err
        assert len(err.strip().splitlines()) == 1
