"""Learned intersection flags for a segment field (SALS's o, s on the grid edges), in the spirit of
UNDC: a grid network reads the field around each grid edge and decides whether the edge crosses the
surface; E-DC then builds the mesh from the flagged edges (``sals-ndc``, :mod:`methods.fields.sals_ndc`).

Input (:func:`network_input`): 6 channels on the N^3 grid points, per point p and axis a the field
of the grid edge from p along +a: ``o_hat`` (the hit probability, in [0, 1]) and ``s_hat - 1/2``
(where along the edge the hit lies, centred); edges the field does not give (far from the surface,
or leaving the grid) read ``o = 0, s - 1/2 = 0``, and so does the padding of
:data:`~methods.extractors.rec7.RECEPTIVE_PADDING` points on each side. The network is NDC's
``CNN_3d_rec7`` (:class:`~methods.extractors.rec7.Rec7Network`, 6 input and 3 output channels): the
logit of each of the 3 edges from p. Only *candidate* edges can be flagged, those with ``o_hat >
o_low`` (the band the sparse query evaluates); the network runs at their start points alone
(:func:`~methods.extractors.rec7.sparse_forward`), in float64 rounded to float32, so the flags do
not depend on the CPU.

The weights are trained on fitted SALS fields of shapes that are no evaluation part
(:mod:`methods.training.learned_flags`); a weights file records its training shapes (names and
content hashes) and is refused in one line when one of them is an evaluation shape.
"""

from __future__ import annotations

import os
import re
from pathlib import Path

import numpy as np

from foundation.grid import edge_index_to_ijk_axis, ijk_axis_to_edge_index
from methods.core.weights import WeightsError, read_weights_file, write_weights_file
from methods.extractors.rec7 import RECEPTIVE_PADDING, Rec7Network, sparse_forward

#: Input channels: o of the x, y, z edges from a point, then s - 1/2 of the same edges.
IN_CHANNELS = 6
#: Candidate edges: ``o_hat`` above this (the band of the sparse edge query).
DEFAULT_O_LOW = 0.02
#: An edge crosses the surface when the network's logit is above 0 (sigmoid > 1/2).
FLAG_LOGIT = 0.0

#: Environment variable naming the weights file.
WEIGHTS_ENV = "SALSBENCH_SALS_NDC_WEIGHTS"
#: The weights without the variable: ``python -m methods.training.learned_flags --budget cpu``.
DEFAULT_WEIGHTS = Path(__file__).resolve().parents[1] / "weights" / "sals_ndc_cpu.pt"
#: Names of evaluation shapes: ABC parts (8-digit object ids) and the built-in evaluation shapes.
EVALUATION_NAME = re.compile(r"^(\d{8}(_|$)|builtin_)")


def network_input(N: int, edge_ids: np.ndarray, o: np.ndarray, s: np.ndarray) -> np.ndarray:
    """The network's input grid (module docstring): (6, N + 6, N + 6, N + 6) float32.

    Parameters
    ----------
    N : grid points per axis.
    edge_ids : (E,) flat edge ids (:mod:`foundation.grid`) the field is given on.
    o, s : (E,) the field on them: hit probability in [0, 1] and hit position in [0, 1].
    """
    grid = np.zeros((IN_CHANNELS,) + (N + 2 * RECEPTIVE_PADDING,) * 3, dtype=np.float32)
    ijk, axis = edge_index_to_ijk_axis(N, np.asarray(edge_ids, dtype=np.int64))
    at = tuple((ijk + RECEPTIVE_PADDING).T)
    grid[(axis,) + at] = np.asarray(o, dtype=np.float32)
    grid[(axis + 3,) + at] = np.asarray(s, dtype=np.float32) - 0.5
    return grid


def candidate_edges(edge_ids: np.ndarray, o: np.ndarray, o_low: float = DEFAULT_O_LOW) -> np.ndarray:
    """The sorted flat ids of the edges that may be flagged: ``o > o_low``."""
    return np.sort(np.asarray(edge_ids, dtype=np.int64)[np.asarray(o) > o_low])


def edge_logits(network: Rec7Network, N: int, grid: np.ndarray, candidates: np.ndarray) -> np.ndarray:
    """The network's logit of each candidate edge ((C,) float32, in the order of ``candidates``),
    evaluated at the candidates' start points only."""
    if len(candidates) == 0:
        return np.zeros(0, dtype=np.float32)
    ijk, axis = edge_index_to_ijk_axis(N, candidates)
    points, where = np.unique(ijk, axis=0, return_inverse=True)
    out = sparse_forward(network, grid, points)  # (P, 3): the x, y, z edges of each start point
    return out[where.reshape(-1), axis]


def predict_flags(network: Rec7Network, N: int, edge_ids: np.ndarray, o: np.ndarray, s: np.ndarray,
                  o_low: float = DEFAULT_O_LOW) -> np.ndarray:
    """The flat ids (sorted) of the candidate edges (:func:`candidate_edges`) the network flags as
    crossing the surface, from the segment field (``o``, ``s``) on ``edge_ids``."""
    candidates = candidate_edges(edge_ids, o, o_low)
    logits = edge_logits(network, N, network_input(N, edge_ids, o, s), candidates)
    return candidates[logits > FLAG_LOGIT]


def edge_labels(N: int, hit_ids: np.ndarray) -> np.ndarray:
    """(3, N, N, N) bool: the edge from point p along axis a crosses the surface (``hit_ids``: the
    flat ids of the crossing edges); False where an edge would leave the grid."""
    labels = np.zeros((3, N, N, N), dtype=bool)
    ijk, axis = edge_index_to_ijk_axis(N, np.asarray(hit_ids, dtype=np.int64))
    labels[(axis,) + tuple(ijk.T)] = True
    return labels


def edges_of_points(N: int, ijk: np.ndarray, axis: np.ndarray) -> np.ndarray:
    """Flat edge ids of (point, axis) pairs, -1 where the edge would leave the grid."""
    ijk, axis = np.asarray(ijk, dtype=np.int64).reshape(-1, 3), np.asarray(axis, dtype=np.int64).reshape(-1)
    inside = ijk[np.arange(len(ijk)), axis] < N - 1
    ids = np.full(len(ijk), -1, dtype=np.int64)
    ids[inside] = ijk_axis_to_edge_index(N, ijk[inside], axis[inside])
    return ids


# --------------------------------------------------------------------------------------------------
# The weights file
# --------------------------------------------------------------------------------------------------

def weights_path() -> Path:
    """The weights file: ``$SALSBENCH_SALS_NDC_WEIGHTS`` when set, else :data:`DEFAULT_WEIGHTS`."""
    return Path(os.environ.get(WEIGHTS_ENV) or DEFAULT_WEIGHTS)


def save_weights(path: str | Path, network: Rec7Network, info: dict) -> str:
    """Write the network and ``info`` (budget, training shapes, losses...) to ``path``, atomically and
    checksummed; returns the SHA-256 of the payload."""
    return write_weights_file(path, {"network": network.state_dict(), "config": dict(network.config),
                                     "info": dict(info)})


def _training_command(path: Path) -> str:
    return f"python -m methods.training.learned_flags --budget cpu --out {path}"


def load_weights(path: str | Path | None = None) -> tuple[Rec7Network, dict]:
    """(network in eval mode on the CPU, info with ``sha256``) from ``path`` (default
    :func:`weights_path`), after checking its checksum and its training shapes.

    Raises :class:`WeightsError` with one line naming the file: absent (with the command that trains
    it), damaged, or trained on an evaluation shape (:data:`EVALUATION_NAME`)."""
    path = Path(path) if path is not None else weights_path()
    blob, sha256 = read_weights_file(path, "sals-ndc weights", _training_command(path), WEIGHTS_ENV)
    info = {**blob["info"], "sha256": sha256}
    seen = [name for name in info.get("training_names", ()) if EVALUATION_NAME.match(str(name))]
    if seen:
        raise WeightsError(f"{path} was trained on evaluation shape(s) {', '.join(map(str, seen[:3]))}"
                           f"{' ...' if len(seen) > 3 else ''}: refused (train on the built-in training parts)")
    network = Rec7Network(**blob["config"])
    network.load_state_dict(blob["network"])
    return network.eval(), info
