"""Method order and colours in the reports come from the method registry (methods.base.METHODS)."""

from __future__ import annotations

from methods.base import FieldMethod, registered_method
from reports.style import PALETTE, method_colors, method_order


class Late(FieldMethod):
    name = "toy-late"


class Early(FieldMethod):
    name = "toy-early"


def test_order_is_preferred_then_registry_order_then_unknown():
    with registered_method(Late, color="#123456", order=-1), registered_method(Early, color=PALETTE[0], order=-2):
        present = ["old-b", "toy-late", "old-a", "toy-early"]
        assert method_order(present) == ["toy-early", "toy-late", "old-b", "old-a"]
        assert method_order(present, preferred=["toy-late", "absent"]) == ["toy-late", "toy-early", "old-b", "old-a"]


def test_colours_from_registry_and_unused_palette_colours_for_unknown_methods():
    with registered_method(Late, color="#123456", order=-1), registered_method(Early, color=PALETTE[0], order=-2):
        colors = method_colors(["old-a", "toy-late", "toy-early", "old-b"])
    assert colors == {"old-a": PALETTE[1], "toy-late": "#123456", "toy-early": PALETTE[0], "old-b": PALETTE[2]}
    assert list(colors) == ["old-a", "toy-late", "toy-early", "old-b"]
