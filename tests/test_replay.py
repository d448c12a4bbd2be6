"""``python -m jaxgrasp.replay``: frames of one trial, rendered headless (EGL on a CPU)."""

import numpy as np
import pytest
from PIL import Image

import jaxgrasp as jg
from jaxgrasp import replay

#: Side grasp of the 6 x 6 x 10 cm test box at half height: holds (test_backends).
SIDE = [-0.012, 0.0, 0.05, 0.7071, 0.0, 0.7071, 0.0]


@pytest.fixture(scope="module")
def box_frames():
    return replay.render_trial(jg.objects.make_box(), SIDE, every=10, size=(96, 72))


def test_frames_show_the_trial(box_frames):
    frames, outcome = box_frames
    assert outcome == "SUCCESS"  # SIDE holds
    assert len(frames) == 8 and frames[0].shape == (72, 96, 3)  # 80 steps, every 10th
    lit = [float((f.astype(int).sum(-1) > 60).mean()) for f in frames]
    assert min(lit) > 0.02, lit  # the object and gripper are drawn, not a black frame
    moved = np.abs(frames[-1].astype(int) - frames[0].astype(int)).sum(-1) > 30
    assert moved.mean() > 0.001  # the fingers close between the first and last frame


def test_gif_round_trip(box_frames, tmp_path):
    out = replay.save_frames(box_frames[0], tmp_path / "t.gif")
    with Image.open(out) as im:
        assert im.n_frames == len(box_frames[0])
    with pytest.raises(ValueError, match="only .gif"):
        replay.save_frames(box_frames[0], tmp_path / "t.mp4")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["t.gif"]


@pytest.mark.parametrize("grasp, match", [
    ("1,2,3", "7 numbers"), ("a,b,c,d,e,f,g", "comma-separated"),
    ("0,0,0.05,0,0,0,0", "quaternion"), ("0,0,nan,1,0,0,0", "NaN"),
])
def test_bad_grasp_is_a_clear_error(grasp, match, tmp_path, capsys):
    assert replay.main(["pitcher", "--grasp", grasp, "--out", str(tmp_path / "x.gif")]) == 2
    assert match in capsys.readouterr().err
    assert not list(tmp_path.iterdir())
