"""Mesh extraction algorithms: plain functions from a field sampled on the grid to a triangle mesh.

Every extractor is named after its algorithm and follows one convention:

* Input: the field sampled on the grid of :mod:`foundation.grid` (N points per axis on [-1, 1]^3,
  spacing ``h = 2 / (N - 1)``, ``'ij'`` indexing; E-DC: on its edges, by flat edge id), distances
  in canonical units, plus the extractor's own options. Extractors that query the field off the
  grid take callables on canonical points (P, 3) float64.
* Output: a :class:`methods.base.Extraction`: ``vertices`` (n, 3) float64 in the canonical frame,
  ``faces`` (m, 3) int64 indexing them, ``info`` a dict of scalar facts about the extraction
  (counts, the parameters it resolved), recorded with the job.
* Timing: sub-steps are timed inside the extractor with :func:`foundation.timing.stage` (or
  :func:`foundation.timing.record`); called within a job's ``extract`` stage a sub-step ``qef``
  becomes the column ``extract_qef_s``. Outside an active timer these do nothing.

The extractors: :func:`marching_cubes.marching_cubes_grid` (signed fields),
:func:`edc.edge_dual_contouring` (E-DC, SALS's edge field),
:func:`meshudf.meshudf_marching_cubes`, :func:`dualmesh.dualmesh_udf` and :func:`dcudf.dcudf`
(unsigned distance fields), :func:`ndc.neural_dual_contouring` (SDF) and
:func:`undc.unsigned_neural_dual_contouring` (UDF). :mod:`mesh_ops` holds the mesh operations they
share (dropping vertices and reindexing the faces), :mod:`meshlab` the pymeshlab steps of the
point-cloud baselines. The extractors that belong to one point-cloud method live beside it and
follow the same convention (``methods.pointcloud.gifs.extraction.flag_split_marching_cubes``,
``methods.pointcloud.geoudf.extraction.edge_marching_cubes``,
``methods.pointcloud.cap_udf.extraction.gradient_sign_marching_cubes``).
"""
