"""External mesh sources: one adapter per layout (folder, shapenet, buildingnet, meshfleet, carla),
all behind :class:`catalog.sources.base.SourceAdapter`."""
