"""Skeleton: the joint tree of a BVH file (names, parents, offsets, channel layout).

Conventions (BVH):
    * joints are stored in file order, which is depth-first, so a parent always comes
      before its children (``parents[j] < j``; the root has parent -1);
    * a joint's rotation is the product of its rotation channels in the order listed, e.g.
      ``Zrotation Yrotation Xrotation`` gives ``R = Rz(z) @ Ry(y) @ Rx(x)`` (angles in degrees);
    * a joint with position channels takes its local translation from those channels instead of
      its OFFSET (the Bandai files rely on this; for the CMU root OFFSET is zero either way).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from bayesmotion.errors import BayesmotionError

POSITION_CHANNELS = ("Xposition", "Yposition", "Zposition")
ROTATION_CHANNELS = ("Xrotation", "Yrotation", "Zrotation")
VALID_CHANNELS = POSITION_CHANNELS + ROTATION_CHANNELS
UP_AXIS = 1  # Y is up in BVH files from CMU and Bandai


@dataclass(frozen=True, eq=False)
class Skeleton:
    """A joint tree.

    Attributes:
        names: (J,) joint names, unique, in file (depth-first) order.
        parents: (J,) index of each joint's parent, -1 for the root.
        offsets: (J, 3) joint offsets from the parent, in the file's length unit.
        channels: (J,) tuple of channel names per joint, e.g. ``("Zrotation", "Yrotation",
            "Xrotation")``.
        end_sites: mapping ``joint index -> (3,) offset`` of the End Site below that joint.
    """

    names: tuple[str, ...]
    parents: tuple[int, ...]
    offsets: np.ndarray
    channels: tuple[tuple[str, ...], ...]
    end_sites: dict[int, np.ndarray] = field(default_factory=dict)

    def __post_init__(self):
        try:
            offsets = np.array(self.offsets, dtype=np.float64).reshape(-1, 3)
            ends = {int(k): np.array(v, dtype=np.float64).reshape(3)
                    for k, v in self.end_sites.items()}
        except (TypeError, ValueError) as e:
            raise BayesmotionError(f"Skeleton offsets must be (J, 3) numbers: {e}") from None
        offsets.setflags(write=False)
        object.__setattr__(self, "offsets", offsets)
        object.__setattr__(self, "names", tuple(self.names))
        object.__setattr__(self, "parents", tuple(int(p) for p in self.parents))
        object.__setattr__(self, "channels", tuple(tuple(c) for c in self.channels))
        object.__setattr__(self, "end_sites", ends)
        self._validate()

    def _validate(self):
        J = len(self.names)
        if J == 0:
            raise BayesmotionError("Skeleton has no joints")
        if len(self.parents) != J or self.offsets.shape != (J, 3) or len(self.channels) != J:
            raise BayesmotionError(
                f"Skeleton fields disagree: {J} names, {len(self.parents)} parents, "
                f"{self.offsets.shape[0]} offsets, {len(self.channels)} channel lists"
            )
        bad_names = [n for n in self.names if not isinstance(n, str) or not n
                     or any(ch.isspace() for ch in n) or n in ("{", "}")]
        if bad_names:
            raise BayesmotionError(f"Skeleton joint names must be non-empty and free of "
                                   f"whitespace and braces (BVH tokens), got {bad_names}")
        if not np.all(np.isfinite(self.offsets)) or not all(
                np.all(np.isfinite(v)) for v in self.end_sites.values()):
            raise BayesmotionError("Skeleton offsets (and End Site offsets) must be finite")
        if len(set(self.names)) != J:
            dup = sorted({n for n in self.names if self.names.count(n) > 1})
            raise BayesmotionError(f"Skeleton has duplicate joint names: {dup}")
        if self.parents[0] != -1 or any(not (-1 <= p < j) for j, p in enumerate(self.parents)):
            raise BayesmotionError("Skeleton parents must be depth-first: parents[j] < j, root -1")
        if any(p == -1 for p in self.parents[1:]):
            raise BayesmotionError("Skeleton has more than one root")
        for name, chans in zip(self.names, self.channels, strict=True):
            bad = [c for c in chans if c not in VALID_CHANNELS]
            if bad or len(set(chans)) != len(chans):
                raise BayesmotionError(f"joint {name!r}: invalid channel list {list(chans)}")
        for k in self.end_sites:
            if not 0 <= k < J:
                raise BayesmotionError(f"End Site attached to unknown joint index {k}")

    # ------------------------------------------------------------------ layout
    @property
    def n_joints(self) -> int:
        return len(self.names)

    @property
    def n_channels(self) -> int:
        return sum(len(c) for c in self.channels)

    @property
    def channel_offsets(self) -> np.ndarray:
        """(J+1,) start index of each joint's channels in a frame row (cumulative)."""
        return np.concatenate([[0], np.cumsum([len(c) for c in self.channels])]).astype(int)

    @property
    def channel_names(self) -> tuple[str, ...]:
        """(C,) ``"joint:channel"`` for every column of a frame row."""
        return tuple(f"{n}:{c}" for n, chans in zip(self.names, self.channels, strict=True)
                     for c in chans)

    def index(self, name: str) -> int:
        """Index of joint ``name``; raises a BayesmotionError naming the joint if absent."""
        try:
            return self.names.index(name)
        except ValueError:
            raise BayesmotionError(f"skeleton has no joint named {name!r}") from None

    def rotation_layout(self) -> tuple[np.ndarray, tuple[str, ...]]:
        """Column indices of each joint's rotation channels and their order.

        Returns:
            idx: (J, 3) int, columns of the rotation channels in listed order (-1: none).
            orders: (J,) strings such as ``"ZYX"`` ("" for joints without rotation).
        """
        starts = self.channel_offsets
        idx = -np.ones((self.n_joints, 3), dtype=int)
        orders = []
        for j, chans in enumerate(self.channels):
            rot = [(starts[j] + k, c[0]) for k, c in enumerate(chans) if c in ROTATION_CHANNELS]
            for k, (col, _) in enumerate(rot):
                idx[j, k] = col
            orders.append("".join(a for _, a in rot))
        return idx, tuple(orders)

    def position_layout(self) -> np.ndarray:
        """(J, 3) column of the X/Y/Z position channels of each joint (-1: none)."""
        starts = self.channel_offsets
        idx = -np.ones((self.n_joints, 3), dtype=int)
        for j, chans in enumerate(self.channels):
            for k, c in enumerate(chans):
                if c in POSITION_CHANNELS:
                    idx[j, POSITION_CHANNELS.index(c)] = starts[j] + k
        return idx

    @property
    def root_position_columns(self) -> np.ndarray:
        """(3,) columns of the root's X/Y/Z position channels (-1 where absent)."""
        return self.position_layout()[0]

    def size(self) -> float:
        """A characteristic length: the sum of the longest root-to-leaf chain of offsets."""
        depth = np.zeros(self.n_joints)
        for j, p in enumerate(self.parents):
            if p >= 0:
                depth[j] = depth[p] + np.linalg.norm(self.offsets[j])
        ends = [depth[k] + np.linalg.norm(v) for k, v in self.end_sites.items()]
        return float(max([depth.max(), *ends]) or 1.0)

    def children(self, j: int) -> list[int]:
        return [k for k, p in enumerate(self.parents) if p == j]

    def same_layout(self, other: Skeleton) -> bool:
        """True when both skeletons have the same joints, tree and channels (offsets may differ)."""
        return (self.names == other.names and self.parents == other.parents
                and self.channels == other.channels)

    def with_offsets(self, offsets: np.ndarray) -> Skeleton:
        return Skeleton(self.names, self.parents, offsets, self.channels, self.end_sites)

    # ------------------------------------------------------------ serialisation
    def to_dict(self) -> dict:
        """JSON-safe description (used by model files)."""
        return {
            "names": list(self.names),
            "parents": list(self.parents),
            "offsets": self.offsets.tolist(),
            "channels": [list(c) for c in self.channels],
            "end_sites": {str(k): v.tolist() for k, v in self.end_sites.items()},
        }

    @classmethod
    def from_dict(cls, d: dict) -> Skeleton:
        try:
            return cls(d["names"], d["parents"], np.asarray(d["offsets"], dtype=float),
                       d["channels"], {int(k): v for k, v in d.get("end_sites", {}).items()})
        except (KeyError, TypeError, ValueError) as e:
            raise BayesmotionError(f"invalid skeleton description: {e}") from None


def horizontal_columns(skeleton: Skeleton, mover: int = 0) -> np.ndarray:
    """Indices of ``mover``'s horizontal (non-up) position channels in a frame's values."""
    cols = skeleton.position_layout()[mover]
    return np.array([cols[a] for a in range(3) if a != UP_AXIS and cols[a] >= 0], dtype=int)
