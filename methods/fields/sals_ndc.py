"""``sals-ndc``: the ``sals`` method's segment field with learned intersection flags, then E-DC.

The field is the ``sals`` method's: the same targets and loss, and in neural mode the same fitted
network (``fit_of = 'sals'``: one fit serves both). Extraction: a grid network
(:mod:`methods.extractors.learned_flags`, NDC's CNN_3d_rec7 on 6 channels) reads the fitted o_hat and
s_hat of the grid edges around each candidate edge (o_hat > ``o_low``, the band of the sparse edge
query) and flags the edges that cross the surface; E-DC (:func:`methods.extractors.edc.edge_dual_contouring`)
builds the mesh from the flagged edges with the fitted s_hat and, with ``normals``, the network's
normals there (as ``sals``). The flags replace ``sals``'s threshold on o_hat; everything after them
is ``sals``'s extraction. The network is trained on fitted SALS fields of the built-in training
parts and the Thingi10K meshes (:mod:`methods.training.learned_flags`); every row says whether its
shape was among them (``seen_in_training``).
Oracle: the exact segment field on the grid (o = 1 on the crossing edges, their exact s) read by the
same network, with the exact normals: how much the network loses on a perfect field.
The network's seconds are the sub-stage ``flags`` of the query (neural) or of the oracle query.
"""

from __future__ import annotations

import numpy as np

from foundation.params import Param
from foundation.timing import stage
from methods.base import register_method
from methods.core.segment_field import band_field, nearer_endpoint_normals
from methods.core.training_record import TrainingRecord
from methods.core.weights import WeightsError, load_cached
from methods.extractors import learned_flags
from methods.fields.sals import SALSMethod


def _load():
    """The weights file's networks and info, read once per process while the file is unchanged."""
    return load_cached(learned_flags.weights_path(), learned_flags.load_weights)


@register_method(order=41, color="#b8336a")
class SALSNDCMethod(SALSMethod):
    name = "sals-ndc"
    description = "the sals method's field + learned intersection flags (a grid CNN, our weights) + E-DC"
    extractor = "learned flags + E-DC"
    fit_of = "sals"
    parameters = {
        **{k: p for k, p in SALSMethod.parameters.items() if k not in ("o_threshold", "o_calibration", "o_low")},
        "o_low": Param(learned_flags.DEFAULT_O_LOW, "candidate edges, which the network may flag: o_hat above this "
                       "(also the band of the sparse query)", gt=0, lt=1),
    }

    @classmethod
    def unavailable(cls):
        try:
            _load()
        except WeightsError as exc:
            return str(exc)
        return None

    def extraction_data_digest(self) -> str:
        return _load()[1]["sha256"]

    def training_record(self) -> TrainingRecord:
        info = _load()[1]
        return TrainingRecord(f"our sals-ndc weights ({info['sha256'][:12]}), {len(info['training_names'])} training "
                              f"shapes (training set {info['training_set']})",
                              content_hashes=frozenset(info["training_hashes"]))

    def calibrate(self, model, fields, N, rng, device=None):
        return {}

    def neural_grid(self, model, N, device=None):
        ids, o, s, fraction = band_field(model, N, self.params["o_low"], device, self.params["stride"])
        network, _ = _load()
        with stage("flags"):
            flagged = learned_flags.predict_flags(network, N, ids, o, s, self.params["o_low"])
        s_flagged = s[np.searchsorted(ids, flagged)]
        normals = None
        if self.params["normals"] and len(flagged):
            from foundation.grid import edge_inputs
            from methods.core import query

            _, g = query.evaluate_with_input_grad(model, edge_inputs(N, flagged), 1, device)
            normals = nearer_endpoint_normals(s_flagged, g)
        facts = {"query_fraction": fraction, "candidate_edges": int((o > self.params["o_low"]).sum()),
                 "flagged_edges": int(len(flagged))}
        return {"edge_ids": flagged, "s": s_flagged, "normals": normals}, facts

    def exact_grid(self, fields, N, cache):
        """The exact segment field (``sals``' oracle field): its crossing edges, not the network's flags."""
        return SALSMethod.oracle_grid(self, fields, N, cache)[0]

    def oracle_grid(self, fields, N, cache):
        ef = cache.get(fields, N, "edges")
        hits = np.flatnonzero(ef.hit)
        network, _ = _load()
        with stage("flags"):
            flagged = learned_flags.predict_flags(network, N, hits, np.ones(len(hits), dtype=np.float32), ef.s[hits],
                                                  self.params["o_low"])
        return {"edge_ids": flagged, "s": ef.s[flagged], "normals": ef.normal[flagged]}, \
            {"flagged_edges": int(len(flagged)), "candidate_edges": int(len(hits))}
