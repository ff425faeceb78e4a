"""Layout design: the objective of method.md §5 and the quality-diversity search over layouts."""
