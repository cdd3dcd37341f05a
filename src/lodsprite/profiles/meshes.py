"""Former home of the mesh helpers, now :mod:`lodsprite.meshes`; re-exported until the
last importer moves."""

from lodsprite.meshes import (  # noqa: F401
    MESH_EXTENSIONS,
    Mesh,
    MeshError,
    bounding_sphere,
    check_mesh_arrays,
    compact_mesh,
    load_mesh,
    mesh_digest,
    uv_sphere,
    vertex_colors,
)
