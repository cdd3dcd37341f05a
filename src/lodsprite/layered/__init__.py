"""A scene's layers in one frame (issue 23): terrain, objects and light fields composited
by depth, under one frame budget.

* :mod:`.layers` - :class:`~.layers.Layer`, :func:`~.layers.layer_frame`, the terrain layer;
* :mod:`.objects` - the objects layer (the LODManager engine over a world's instances);
* :mod:`.lightfields` - the light-field layer (reconstruction composited by proxy depth);
* :mod:`.technique` - :class:`~.technique.LayeredTechnique`, registered as ``scene``;
  its :func:`~.technique.render_scene` is ``lodsprite render --scene``.

A package above the technique packages (it draws with the terrain techniques, the
LODManager engine and the lumigraph's methods); the registry names it by dotted path.
"""
