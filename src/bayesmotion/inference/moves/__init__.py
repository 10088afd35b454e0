"""emcee moves for the hierarchical posterior, one per module (as in emcee): rotations along the
style vectors' symmetry orbits (exact, and free of GP evaluations), ensemble-preconditioned HMC
on a block of coordinates and independence Metropolis on a block; :class:`Sequence` composes
them within one step."""

from bayesmotion.inference.moves.hmc import EnsembleHMC
from bayesmotion.inference.moves.independence import IndependenceMove
from bayesmotion.inference.moves.rotations import StyleRotations, plane_rotations, style_slices
from bayesmotion.inference.moves.sequence import Sequence

__all__ = ["EnsembleHMC", "IndependenceMove", "Sequence", "StyleRotations", "plane_rotations",
           "style_slices"]
