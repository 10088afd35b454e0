"""emcee moves for the hierarchical posterior, one per module (as in emcee): rotations along the
style vectors' symmetry orbits (exact, and free of GP evaluations), ensemble-preconditioned HMC
on a block of coordinates, independence Metropolis on a block (its proposal optionally a t after
per-coordinate sinh-arcsinh maps, :class:`SinhArcsinh`), and differential evolution in
coordinates where the output scales do not trade off against the style norms
(:class:`ShearedDE`) and, for the rotated style vectors, on what the likelihood sees of them
(:class:`CanonicalDE`); :class:`Sequence` composes them within one step."""

from bayesmotion.inference.moves.canonical import (
    CanonicalDE,
    CanonicalIndependence,
    CanonicalStyles,
)
from bayesmotion.inference.moves.hmc import EnsembleHMC
from bayesmotion.inference.moves.independence import IndependenceMove
from bayesmotion.inference.moves.marginal import SinhArcsinh
from bayesmotion.inference.moves.rotations import (
    StyleRotations,
    plane_basis,
    plane_rotations,
    style_slices,
)
from bayesmotion.inference.moves.sequence import Sequence
from bayesmotion.inference.moves.shear import ShearedDE, StyleShear

__all__ = ["CanonicalDE", "CanonicalIndependence", "CanonicalStyles", "EnsembleHMC",
           "IndependenceMove", "Sequence", "ShearedDE", "SinhArcsinh", "StyleRotations",
           "StyleShear", "plane_basis", "plane_rotations", "style_slices"]
