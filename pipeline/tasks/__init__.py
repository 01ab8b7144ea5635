"""One wiring module per stage: its spec (partitions, prepare, config), and its task body, which
reads a partition's inputs through the catalog, calls the pure compute of ``carlaocc.stages`` and
writes the outputs through the catalog, returning their fingerprints.

* ``ingest``   — the procedural ADMesh library; an external mesh source, one task per item
* ``scenes``   — one task per town: layout, placements, traffic, sequences, actors
* ``splits``   — one task: train / val / test by sequence into ``splits/``
* ``voxelize`` — one task per (sequence, voxel size, frame): occupancy, flow, visibility masks
* ``sensors``  — one task per (sequence, frame): camera maps, LiDAR, rectification, normals
* ``quality``  — one task per (sequence, voxel size): spatial continuity, temporal consistency
* ``report``   — one task: statistics, plots and ``metrics/report.html`` (page in ``report_page``)
* ``frame``    — what per-frame tasks read: a frame's rows and panoptic scene, asset geometry
* ``partitions`` — what partitioning shares: partition keys other stages name, the sequences

These are the only functions that know both where data lives and what computes it. They run
inside Dask workers, so they take a store (a URL) and a frozen config, never open objects.
"""
