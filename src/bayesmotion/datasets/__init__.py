"""Built-in and real data sets.

* :func:`load_cmu_handshake` -- the real CMU two-person handshake (subjects 18 and 19), shipped
  with the package.
* :func:`load_handshakes` -- an emotional handshake set derived from it (synthetic emotion
  labels applied to real motion; see its docstring).
* :func:`load_bandai` -- the Bandai-Namco emotional motion set, read from a local copy.

The CMU data: "The data used in this project was obtained from mocap.cs.cmu.edu. The database
was created with funding from NSF EIA-0196217."
"""

from bayesmotion.datasets.bandai import load_bandai
from bayesmotion.datasets.handshakes import load_cmu_handshake, load_handshakes

__all__ = ["load_bandai", "load_cmu_handshake", "load_handshakes"]
