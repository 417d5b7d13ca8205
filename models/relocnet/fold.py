"""The four output representations, folded exactly as relocd's `geometry::symmetry` folds them.

Canonical regions: half-point x <= 0 (half-open on the cut, see the Rust docs), half-line y >= 0,
quarter x <= 0 and y >= 0. One bit per generator, in the same order as in Rust.
"""

import numpy as np

REPRESENTATIONS = ("full", "half-point", "half-line", "quarter")
FOLD_BITS = {"full": 0, "half-point": 1, "half-line": 1, "quarter": 2}


def wrap(angle):
    """Wraps angles into (-pi, pi]."""
    wrapped = np.mod(angle, 2 * np.pi)
    return np.where(wrapped > np.pi, wrapped - 2 * np.pi, wrapped)


def _point_reflection(x, y, theta, flip):
    return np.where(flip, -x, x), np.where(flip, -y, y), np.where(flip, wrap(theta + np.pi), theta)


def _mirror_long_axis(x, y, theta, flip):
    return x, np.where(flip, -y, y), np.where(flip, wrap(-theta), theta)


def _mirror_short_axis(x, y, theta, flip):
    return np.where(flip, -x, x), y, np.where(flip, wrap(np.pi - theta), theta)


def fold(x, y, theta, representation):
    """Folds full-field poses (arrays) into the canonical region: returns (x, y, theta, bits[N, k])."""
    x, y, theta = (np.asarray(v, dtype=np.float64) for v in (x, y, theta))
    bits = []
    if representation == "half-point":
        at_centre = (x == 0) & (y == 0)
        keep = (x < 0) | ((x == 0) & (y > 0)) | (at_centre & (theta > -np.pi / 2) & (theta <= np.pi / 2))
        x, y, theta = _point_reflection(x, y, theta, ~keep)
        bits.append(~keep)
    elif representation == "half-line":
        flip = y < 0
        x, y, theta = _mirror_long_axis(x, y, theta, flip)
        bits.append(flip)
    elif representation == "quarter":
        flip_long = y < 0
        x, y, theta = _mirror_long_axis(x, y, theta, flip_long)
        flip_short = x > 0
        x, y, theta = _mirror_short_axis(x, y, theta, flip_short)
        bits += [flip_long, flip_short]
    elif representation != "full":
        raise ValueError(f"unknown representation {representation!r}: expected one of {REPRESENTATIONS}")
    bits = np.stack(bits, axis=-1).astype(np.float32) if bits else np.zeros((len(x), 0), np.float32)
    return x, y, theta, bits


def mirror_long_axis(x, y, theta):
    """The pose whose camera image is the horizontal mirror image: (x, -y, -theta)."""
    return x, -y, wrap(-theta)
