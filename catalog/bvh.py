"""BVH (Biovision Hierarchy) motion-capture reader.

``read_bvh(path)`` / ``parse_bvh(text)`` return a :class:`~carlaocc.schemas.motion.MotionClip`
holding the skeleton exactly as the file states it -- no unit or axis conversion happens here
(BVH is Y-up; the Y-up -> Z-up conversion is done once, in
:func:`carlaocc.stages.scenes.people.gait.kinematics.forward_kinematics`).

``End Site`` blocks are kept as ``end_offsets`` (NaN rows for joints without one); they carry no
channels. Malformed input raises :class:`BvhError` naming the 1-based line number.
"""

from __future__ import annotations

import fsspec
import numpy as np

from carlaocc.schemas.motion import MotionClip

VALID_CHANNELS = frozenset({"Xposition", "Yposition", "Zposition", "Xrotation", "Yrotation", "Zrotation"})


class BvhError(ValueError):
    """Malformed BVH input; the message names the offending line."""


def _floats(tokens: list[str], lineno: int, what: str) -> list[float]:
    try:
        return [float(t) for t in tokens]
    except ValueError:
        raise BvhError(f"line {lineno}: {what}: expected numbers, got {' '.join(tokens)!r}") from None


def parse_bvh(text: str) -> MotionClip:
    """Parse BVH text into a :class:`~carlaocc.schemas.motion.MotionClip`; raise :class:`BvhError` on malformed input."""
    lines = text.splitlines()
    names: list[str] = []
    parents: list[int] = []
    offsets: list[list[float]] = []
    channels: list[tuple[str, ...]] = []
    end_offsets: list[list[float]] = []
    stack: list[int] = []  # joint indices of open blocks (-2 marks an End Site block)
    pending: int | None = None  # joint declared, waiting for its "{"
    i = 0
    n = len(lines)

    def next_nonblank(k: int) -> int:
        while k < n and not lines[k].strip():
            k += 1
        return k

    i = next_nonblank(0)
    if i >= n or lines[i].strip() != "HIERARCHY":
        raise BvhError(f"line {i + 1}: expected 'HIERARCHY'")
    i += 1
    saw_root = False
    while True:
        i = next_nonblank(i)
        if i >= n:
            raise BvhError(f"line {n}: unexpected end of file in HIERARCHY (missing MOTION)")
        lineno = i + 1
        tok = lines[i].split()
        key = tok[0]
        if key in ("ROOT", "JOINT"):
            if key == "ROOT" and (saw_root or stack):
                raise BvhError(f"line {lineno}: second ROOT or ROOT inside a joint block")
            if key == "JOINT" and (not stack or stack[-1] < 0):
                raise BvhError(f"line {lineno}: JOINT outside a joint block")
            if len(tok) < 2:
                raise BvhError(f"line {lineno}: {key} without a name")
            saw_root = True
            names.append(" ".join(tok[1:]))
            parents.append(stack[-1] if stack else -1)
            offsets.append([np.nan] * 3)
            channels.append(())
            end_offsets.append([np.nan] * 3)
            pending = len(names) - 1
        elif key == "End":
            if not stack or stack[-1] < 0:
                raise BvhError(f"line {lineno}: End Site outside a joint block")
            pending = -2
        elif key == "{":
            if pending is None:
                raise BvhError(f"line {lineno}: '{{' without a ROOT/JOINT/End Site")
            stack.append(pending if pending >= 0 else -2 - stack[-1])  # End Site: -2 - owner
            pending = None
        elif key == "}":
            if not stack:
                raise BvhError(f"line {lineno}: unbalanced '}}'")
            stack.pop()
        elif key == "OFFSET":
            if not stack:
                raise BvhError(f"line {lineno}: OFFSET outside a block")
            vals = _floats(tok[1:], lineno, "OFFSET")
            if len(vals) != 3:
                raise BvhError(f"line {lineno}: OFFSET needs 3 values, got {len(vals)}")
            top = stack[-1]
            if top >= 0:
                offsets[top] = vals
            else:
                end_offsets[-2 - top] = vals
        elif key == "CHANNELS":
            if not stack or stack[-1] < 0:
                raise BvhError(f"line {lineno}: CHANNELS outside a joint block")
            if len(tok) < 2:
                raise BvhError(f"line {lineno}: CHANNELS without a count")
            try:
                count = int(tok[1])
            except ValueError:
                raise BvhError(f"line {lineno}: bad channel count {tok[1]!r}") from None
            chans = tuple(tok[2:])
            if count != len(chans):
                raise BvhError(f"line {lineno}: CHANNELS says {count} but lists {len(chans)}")
            bad = [c for c in chans if c not in VALID_CHANNELS]
            if bad:
                raise BvhError(f"line {lineno}: unknown channel(s) {bad}")
            channels[stack[-1]] = chans
        elif key == "MOTION":
            if stack:
                raise BvhError(f"line {lineno}: MOTION before the hierarchy is closed")
            if not names:
                raise BvhError(f"line {lineno}: MOTION without a ROOT")
            i += 1
            break
        else:
            raise BvhError(f"line {lineno}: unexpected token {key!r} in HIERARCHY")
        i += 1

    for j, off in enumerate(offsets):
        if np.isnan(off).any():
            raise BvhError(f"joint {names[j]!r} has no OFFSET")

    i = next_nonblank(i)
    if i >= n or not lines[i].strip().startswith("Frames:"):
        raise BvhError(f"line {min(i, n - 1) + 1}: expected 'Frames: <count>'")
    try:
        n_frames = int(lines[i].split(":", 1)[1])
    except ValueError:
        raise BvhError(f"line {i + 1}: bad frame count") from None
    if n_frames < 0:
        raise BvhError(f"line {i + 1}: negative frame count")
    i = next_nonblank(i + 1)
    if i >= n or not lines[i].strip().startswith("Frame Time:"):
        raise BvhError(f"line {min(i, n - 1) + 1}: expected 'Frame Time: <seconds>'")
    try:
        frame_time = float(lines[i].split(":", 1)[1])
    except ValueError:
        raise BvhError(f"line {i + 1}: bad frame time") from None
    if not frame_time > 0:
        raise BvhError(f"line {i + 1}: frame time must be positive")
    i += 1

    n_channels = sum(len(c) for c in channels)
    motion = np.empty((n_frames, n_channels), dtype=np.float64)
    f = 0
    while f < n_frames:
        if i >= n:
            raise BvhError(f"line {n}: MOTION truncated: {f} of {n_frames} frames present")
        tok = lines[i].split()
        if tok:
            vals = _floats(tok, i + 1, f"frame {f}")
            if len(vals) != n_channels:
                raise BvhError(f"line {i + 1}: frame {f} has {len(vals)} values, hierarchy declares {n_channels} channels")
            motion[f] = vals
            f += 1
        i += 1
    if any(lines[k].strip() for k in range(i, n)):
        k = next(k for k in range(i, n) if lines[k].strip())
        raise BvhError(f"line {k + 1}: more frame lines than 'Frames: {n_frames}'")

    par = np.asarray(parents, dtype=np.int64)
    offs = np.asarray(offsets, dtype=np.float64)
    ends = np.asarray(end_offsets, dtype=np.float64)
    for a in (par, offs, ends, motion):
        a.flags.writeable = False
    return MotionClip(tuple(names), par, offs, tuple(channels), frame_time, motion, ends)


def read_bvh(path: str) -> MotionClip:
    """Read a BVH file (local path or fsspec URL) in place."""

    with fsspec.open(str(path), "rt", encoding="utf-8") as fh:
        text = fh.read()
    try:
        return parse_bvh(text)
    except BvhError as exc:
        raise BvhError(f"{path}: {exc}") from None
