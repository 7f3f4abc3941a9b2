"""Metric presets: each evaluation protocol as data (:class:`MetricPreset`).

``PRESETS['default']`` is the canonical protocol, ``PRESETS['ndc']`` reproduces Neural Dual
Contouring's evaluation script. The preset also states what the reports show: its headline
metrics (:meth:`MetricPreset.headline_metrics`) and its protocol text
(:meth:`MetricPreset.describe_items`), and :func:`f1_column` is the one naming rule of F1 columns.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

from foundation.registry import Registry

__all__ = ["HeadlineMetric", "f1_column", "MetricPreset", "DEFAULT", "NDC", "SCENE", "PRESETS", "get_preset"]


@dataclass(frozen=True)
class HeadlineMetric:
    """A reported metric: result column, display name, table multiplier, better direction."""

    column: str
    name: str
    scale: float
    lower_is_better: bool


def f1_column(tau: float) -> str:
    """Result column of the F1 score at threshold ``tau``: 0.005 -> 'f1_005', 0.01 -> 'f1_01'
    (the digits after '0.'; other values: '.' -> '_'). The one naming rule of F1 columns."""
    text = f"{tau:.10f}".rstrip("0").rstrip(".")
    return "f1_" + (text[2:] if text.startswith("0.") else text.replace(".", "_"))


@dataclass(frozen=True)
class MetricPreset:
    """One evaluation protocol, as data. Every length is in the preset's ``frame``.

    Attributes
    ----------
    name : preset name ('default', 'ndc').
    n_points : surface samples per mesh.
    frame : 'canonical' (inputs are used as given: the GT's canonical frame),
        'diag1' (both meshes mapped by ``x -> (x - c) / D``, c and D the GT bounding-box centre and
        diagonal: NDC's frame) or 'metres' (both meshes scaled by the GT's metres per canonical
        unit, which the caller passes: a scene's metric frame).
    chamfer : 'l1_half_mean' -> ``1/2 (mean d(g->P) + mean d(p->G))``; 'squared_sum' ->
        ``mean d(g->P)^2 + mean d(p->G)^2``.
    cd_scale : multiplier for tables (the returned value is raw).
    f1_thresholds : F1 thresholds tau (absolute, in the frame); F1 counts ``d < tau``.
    edge_units : 'gt_diagonal' (edge radius and EF1 threshold are multiples of the GT
        bounding-box diagonal D in the frame) or 'frame' (absolute lengths in the frame).
    edge_radius : edge-point radius r (in ``edge_units``); neighbours count when ``|p - q| <= r``.
    edge_dot_threshold : q makes p an edge point when ``|n_p . n_q| < edge_dot_threshold``.
    ef1_threshold : EF1 threshold tau_e (in ``edge_units``).
    ecd : chamfer form of ECD ('l1_half_mean' or 'squared_sum').
    ecd_scale : multiplier for tables.
    empty_edge_fallback : 0 -> a prediction without edge points gets ECD = NaN (flagged), EF1 = 0;
        k > 0 -> it is given k edge points at the frame origin and scored (NDC uses 486).
    """

    name: str
    n_points: int
    frame: str
    chamfer: str
    cd_scale: float
    f1_thresholds: tuple[float, ...]
    edge_units: str
    edge_radius: float
    edge_dot_threshold: float
    ef1_threshold: float
    ecd: str
    ecd_scale: float
    empty_edge_fallback: int

    def __post_init__(self):
        if self.frame not in ("canonical", "diag1", "metres"):
            raise ValueError(f"preset {self.name}: frame must be 'canonical', 'diag1' or 'metres', got {self.frame!r}")
        for what in (self.chamfer, self.ecd):
            if what not in ("l1_half_mean", "squared_sum"):
                raise ValueError(f"preset {self.name}: chamfer form must be 'l1_half_mean' or 'squared_sum', got {what!r}")
        if self.edge_units not in ("gt_diagonal", "frame"):
            raise ValueError(f"preset {self.name}: edge_units must be 'gt_diagonal' or 'frame', got {self.edge_units!r}")

    @property
    def f1_keys(self) -> tuple[str, ...]:
        """Result keys of the F1 scores: 'f1_005' for tau = 0.005, 'f1_01' for 0.01, ..."""
        return tuple(f1_column(t) for t in self.f1_thresholds)

    @property
    def report_scale(self) -> dict[str, float]:
        """Table multipliers per result key (keys not listed are reported as is)."""
        return {
            "cd": self.cd_scale,
            "cd_gt_to_pred": self.cd_scale,
            "cd_pred_to_gt": self.cd_scale,
            "ecd": self.ecd_scale,
        }

    def headline_metrics(self) -> list["HeadlineMetric"]:
        """The reported metrics in paper order (CD, NC, F1@tau..., ECD, EF1) with their table
        multipliers and better directions: what every table and plot shows."""
        out = [HeadlineMetric("cd", "CD", self.cd_scale, True), HeadlineMetric("nc", "NC", 1.0, False)]
        out += [HeadlineMetric(k, f"F1@{t:g}", 1.0, False) for t, k in zip(self.f1_thresholds, self.f1_keys)]
        out += [HeadlineMetric("ecd", "ECD", self.ecd_scale, True), HeadlineMetric("ef1", "EF1", 1.0, False)]
        return out

    def describe_items(self, n_points: int | None = None) -> list[tuple[str, str]]:
        """(label, value) pairs stating the protocol, for table captions and the HTML report.
        ``n_points`` overrides the preset's sample count (a run's ``--eval-points``)."""
        unit = " D" if self.edge_units == "gt_diagonal" else ""
        frame = {"canonical": "GT canonical frame (bbox centred, largest side 1.99)",
                 "diag1": "GT bbox centred, diagonal 1 (NDC)",
                 "metres": "GT canonical frame scaled to metres (lengths in m)"}[self.frame]
        chamfer = {"l1_half_mean": "½(mean d(g→P) + mean d(p→G)), unsquared",
                   "squared_sum": "mean d(g→P)² + mean d(p→G)²"}
        items = [
            ("metric preset", self.name),
            ("frame", frame),
            ("points per mesh", f"{int(self.n_points if n_points is None else n_points):,}"),
            ("CD form", f"{chamfer[self.chamfer]} ×{self.cd_scale:g}"),
            ("NC", "|n·n| (orientation-agnostic)"),
            ("F1 thresholds", ", ".join(f"{t:g}" for t in self.f1_thresholds)),
            ("sharp-edge points", f"|p−q| ≤ {self.edge_radius:g}{unit}, |n·n| < {self.edge_dot_threshold:g}"),
            ("ECD form", f"{chamfer[self.ecd]} ×{self.ecd_scale:g}"),
            ("EF1 threshold", f"{self.ef1_threshold:g}{unit}"),
            ("no predicted edge points", "ECD NaN (counted), EF1 = 0" if not self.empty_edge_fallback
             else f"{self.empty_edge_fallback} origin points scored"),
        ]
        if unit:
            items.append(("D", "GT bounding-box diagonal"))
        return items

    def describe(self, n_points: int | None = None) -> str:
        """One line stating the protocol (the items of :meth:`describe_items`)."""
        return "; ".join(f"{k}: {v}" for k, v in self.describe_items(n_points))

    def to_dict(self) -> dict:
        return asdict(self)


#: The canonical protocol.
DEFAULT = MetricPreset(
    name="default",
    n_points=1_000_000,
    frame="canonical",
    chamfer="l1_half_mean",
    cd_scale=1e3,
    f1_thresholds=(0.005, 0.01),
    edge_units="gt_diagonal",
    edge_radius=0.004,
    edge_dot_threshold=0.2,
    ef1_threshold=0.005,
    ecd="l1_half_mean",
    ecd_scale=1e2,
    empty_edge_fallback=0,
)

#: Neural Dual Contouring's evaluation script (Chen et al. 2022, ``eval_cd_nc_f1_ecd_ef1.py``).
NDC = MetricPreset(
    name="ndc",
    n_points=100_000,
    frame="diag1",
    chamfer="squared_sum",
    cd_scale=1e5,
    f1_thresholds=(0.003,),
    edge_units="frame",
    edge_radius=0.004,
    edge_dot_threshold=0.2,
    ef1_threshold=0.005,
    ecd="squared_sum",
    ecd_scale=1e2,
    empty_edge_fallback=486,
)

#: Scenes in metric units (the ``street`` dataset): CD in cm, F-scores at 2, 5 and 10 cm, sharp-edge
#: points within 10 cm, EF1 at 5 cm. Lengths in metres: the GT's ``metres_per_unit`` scales both meshes.
SCENE = MetricPreset(
    name="scene",
    n_points=1_000_000,
    frame="metres",
    chamfer="l1_half_mean",
    cd_scale=1e2,
    f1_thresholds=(0.02, 0.05, 0.1),
    edge_units="frame",
    edge_radius=0.1,
    edge_dot_threshold=0.2,
    ef1_threshold=0.05,
    ecd="l1_half_mean",
    ecd_scale=1e2,
    empty_edge_fallback=0,
)

#: The presets by name (``PRESETS["ndc"]``, ``"ndc" in PRESETS``, ``list(PRESETS)``); an unknown
#: name gets the project's one message: "unknown metric preset 'x'; known metric presets: ...".
PRESETS: Registry[MetricPreset] = Registry("metric preset")
PRESETS.register(DEFAULT.name, DEFAULT)
PRESETS.register(NDC.name, NDC)
PRESETS.register(SCENE.name, SCENE)


def get_preset(preset: str | MetricPreset) -> MetricPreset:
    """``preset`` itself, or the preset of that name (ValueError naming the known presets)."""
    return preset if isinstance(preset, MetricPreset) else PRESETS.get(preset)
