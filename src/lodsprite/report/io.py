"""Former home of the atomic writers, now :mod:`lodsprite.files`; re-exported until the
last importers move."""

from lodsprite.files import (  # noqa: F401
    FILE_MODE,
    atomic_write_bytes,
    save_figure,
    write_csv,
    write_json,
    write_png,
)
