"""BVH reader: the real CMU walk clip (read in place) and malformed inputs."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from carlaocc.catalog.bvh import BvhError, parse_bvh, read_bvh
from carlaocc.schemas.motion import MotionClip
from shared_data import require, shared_path

CLIP = shared_path("motion/cmu_131_01_walk_metres.bvh")

TINY = """HIERARCHY
ROOT Hips
{
  OFFSET 0 0 0
  CHANNELS 6 Xposition Yposition Zposition Zrotation Yrotation Xrotation
  JOINT Leg
  {
    OFFSET 0 -0.5 0
    CHANNELS 3 Zrotation Xrotation Yrotation
    End Site
    {
      OFFSET 0 -0.4 0
    }
  }
}
MOTION
Frames: 2
Frame Time: 0.05
0 1 0 0 0 0 10 20 30
0.1 1 0 0 0 0 11 21 31
"""


@pytest.fixture(scope="module")
def clip() -> MotionClip:
    return read_bvh(str(require(CLIP)))


def test_real_clip_header(clip):
    assert clip.n_joints == 31
    assert clip.n_frames == 995
    assert clip.frame_time == pytest.approx(0.008333)
    assert clip.joint_names[0] == "Hips"
    assert clip.parents[0] == -1 and (clip.parents[1:] >= 0).all()
    assert (clip.parents[1:] < np.arange(1, 31)).all()  # parents first
    assert clip.offsets.shape == (31, 3)
    assert clip.channels[0] == ("Xposition", "Yposition", "Zposition", "Zrotation", "Yrotation", "Xrotation")
    assert all(len(c) == 3 for c in clip.channels[1:])
    assert clip.motion.shape == (995, 6 + 30 * 3) and clip.motion.dtype == np.float64
    assert clip.motion[0, 0] == pytest.approx(0.295202)
    names = clip.joint_names
    assert clip.parents[clip.joint_index("LeftKnee")] == names.index("LeftHip")
    # end sites: toes, head, fingers and thumbs of the CMU skeleton
    assert np.isfinite(clip.end_offsets[:, 0]).sum() == 7


def test_clip_is_frozen(clip):
    with pytest.raises(dataclasses.FrozenInstanceError):
        clip.frame_time = 1.0  # type: ignore[misc]
    with pytest.raises(ValueError):
        clip.motion[0, 0] = 1.0


def test_tiny_clip():
    c = parse_bvh(TINY)
    assert c.joint_names == ("Hips", "Leg")
    assert c.parents.tolist() == [-1, 0]
    assert c.channels[1] == ("Zrotation", "Xrotation", "Yrotation")
    assert c.channel_start.tolist() == [0, 6]
    np.testing.assert_allclose(c.end_offsets[1], [0, -0.4, 0])
    assert np.isnan(c.end_offsets[0]).all()
    assert c.motion[1, 8] == 31


def _line_of(text: str, needle: str) -> int:
    return next(i for i, line in enumerate(text.splitlines(), 1) if needle in line)


def test_truncated_motion_of_real_clip():
    lines = require(CLIP).read_text().splitlines()
    with pytest.raises(BvhError, match=r"line \d+: MOTION truncated: 990 of 995 frames"):
        parse_bvh("\n".join(lines[:-5]) + "\n")


def test_truncated_frame_line():
    text = TINY.rstrip("\n").rsplit(" ", 3)[0] + "\n"  # last frame lost 3 values
    with pytest.raises(BvhError, match=r"line 20: frame 1 has 6 values, hierarchy declares 9 channels"):
        parse_bvh(text)


def test_bad_channel_count():
    text = TINY.replace("CHANNELS 3 Zrotation Xrotation Yrotation", "CHANNELS 4 Zrotation Xrotation Yrotation")
    with pytest.raises(BvhError, match=rf"line {_line_of(text, 'CHANNELS 4')}: CHANNELS says 4 but lists 3"):
        parse_bvh(text)


@pytest.mark.parametrize(
    "old, new, message",
    [
        ("OFFSET 0 -0.5 0", "OFFSET 0 -0.5", r"line 8: OFFSET needs 3 values"),
        ("OFFSET 0 -0.5 0", "OFFSET 0 x 0", r"line 8: OFFSET: expected numbers"),
        ("Zrotation Xrotation Yrotation", "Zrotation Xrotation Wrotation", r"line 9: unknown channel"),
        ("Frames: 2", "Frames: two", r"line 17: bad frame count"),
        ("Frame Time: 0.05", "Frame Time: 0", r"line 18: frame time must be positive"),
        ("0.1 1 0 0 0 0 11 21 31", "0.1 1 0 0 0 0 11 21 3x1", r"line 20: frame 1: expected numbers"),
        ("  }\n}\nMOTION", "  }\nMOTION", r"line 15: MOTION before the hierarchy is closed"),
        ("HIERARCHY", "HIERARCHIE", r"line 1: expected 'HIERARCHY'"),
    ],
)
def test_malformed(old, new, message):
    assert old in TINY
    with pytest.raises(BvhError, match=message):
        parse_bvh(TINY.replace(old, new))


def test_extra_frames_and_missing_motion():
    with pytest.raises(BvhError, match=r"line 21: more frame lines"):
        parse_bvh(TINY + "0 0 0 0 0 0 0 0 0\n")
    with pytest.raises(BvhError, match="missing MOTION"):
        parse_bvh(TINY.split("MOTION")[0])


def test_read_bvh_names_the_path(tmp_path):
    bad = tmp_path / "bad.bvh"
    bad.write_text(TINY.replace("CHANNELS 3", "CHANNELS 2"))
    with pytest.raises(BvhError, match=r"bad\.bvh: line 9"):
        read_bvh(str(bad))
