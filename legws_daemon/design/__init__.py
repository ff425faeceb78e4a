"""Layout design: the objective of method.md §5 and the quality-diversity search over layouts."""

from typing import Literal, get_args

#: Search methods of ``legws optimize`` (kept here, light, for the CLI's option parsing).
Method = Literal["cma-me", "map-elites", "cma-mae"]
METHODS: tuple[str, ...] = get_args(Method)
#: What the search maximises: the slack certificate J (method.md §4); for early commits,
#: minus the commit objective K (method.md §9: the worst goal's certified commit); or the
#: estimated commit rate over all goals (``core.commit.commit_chance_batch``: where K cannot
#: reach 1, as many goals as possible commit before the person arrives); or minus the
#: estimated commit time in seconds (``core.commit.commit_time_batch``: commits early in
#: time, not only in fraction of the way).
Objective = Literal["slack", "commit", "rate", "time"]
OBJECTIVES: tuple[str, ...] = get_args(Objective)
