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
