"""The nine-map layout shared by every stage of the model.

Convention:
    The model takes nine maps in the order ``[R_unpol, G_unpol, B_unpol, R_LP, G_LP, B_LP, R_CP, G_CP, B_CP]``
    (:data:`pbrdf.sensor.decode.NINE_MAP_NAMES`): a 3 x 3 grid whose rows are polarization states (unpolarized,
    linear, circular) and whose columns are colour channels (R, G, B). Map ``n`` has polarization state
    ``MAP_POLARIZATION[n]`` and colour ``MAP_COLOR[n]``; e.g. map 4 is G_LP, state 1 (LP), colour 1 (G).

Example:
    >>> [(MAP_POLARIZATION[n], MAP_COLOR[n]) for n in (0, 4, 8)]
    [(0, 0), (1, 1), (2, 2)]
"""

from __future__ import annotations

__all__ = ["MAP_COLOR", "MAP_POLARIZATION", "NUM_MAPS"]

#: Number of input maps.
NUM_MAPS = 9
#: Polarization state of each map: 0 unpolarized, 1 LP, 2 CP.
MAP_POLARIZATION = (0, 0, 0, 1, 1, 1, 2, 2, 2)
#: Colour channel of each map: 0 R, 1 G, 2 B.
MAP_COLOR = (0, 1, 2, 0, 1, 2, 0, 1, 2)
