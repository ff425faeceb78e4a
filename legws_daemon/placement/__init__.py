"""Printable placement mats: the table at true scale with every object's outline, tiled
over paper pages (``legws placement``)."""
