"""Distributed LOD-sprite (Swan, Arango & Nakshatrala 2002): keyframe server and
spriteframe client.  What to render crosses the process boundary as data
(:mod:`~lodsprite.distributed.protocol`); GL calls happen on each side locally."""
