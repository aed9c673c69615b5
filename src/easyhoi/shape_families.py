"""Names of the silhouette object backend's shape families, importable without the shape code.

The command line offers them (``--object-shape``) and the configuration checks them
(``perception.object_shape``); :data:`easyhoi.perception.shapes.FAMILIES` is the same tuple, in
the same order, as a test checks.
"""

OBJECT_SHAPES = (
    "revolution",
    "superquadric",
    "tube",
    "cuboid",
    "slab",
    "inflation",
    "handled",
)
