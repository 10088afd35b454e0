"""A composition of emcee moves applied in turn within one step."""

from __future__ import annotations

import emcee
import numpy as np


class Sequence(emcee.moves.Move):
    """Applies ``moves`` one after the other at every step; a walker counts as accepted when
    any of them moved it. Each move leaves the target invariant, so their composition does."""

    def __init__(self, *moves):
        if not moves:
            raise ValueError("Sequence needs at least one move")
        self.moves = moves

    def propose(self, model, state):
        accepted = np.zeros(len(state.coords), dtype=bool)
        for move in self.moves:
            state, acc = move.propose(model, state)
            accepted |= np.asarray(acc, dtype=bool)
        return state, accepted
