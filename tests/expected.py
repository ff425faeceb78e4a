"""Facts of the spec the tests check against (method.md §7), in one place."""

from __future__ import annotations

#: Tier, M (candidate goals) and total objects of the paper's six scenes.
PAPER_TIERS: dict[str, tuple[str, int, int]] = {
    "breakfast_easy": ("Easy", 2, 3),
    "desk": ("Med-A", 3, 5),
    "breakfast": ("Med-B", 3, 6),
    "kitchen_prep": ("Med-C", 3, 5),
    "meal_assembly": ("Hard-A", 5, 7),
    "cluttered": ("Hard-B", 8, 11),
}
#: The real-world demos' scenes.
DEMOS = ("tea", "lego", "feeding")
#: Every shipped scene, sorted.
ALL_SCENES = sorted([*PAPER_TIERS, *DEMOS])
