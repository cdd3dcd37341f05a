import pytest

from lodsprite.errors import GLUnavailableError
from lodsprite.gl.context import GLContext


def test_context_reports_gl_33_or_later(gl):
    info = gl.info
    assert info.version_code >= 330
    assert info.max_texture_size >= 4096
    assert info.renderer


def test_missing_backend_gives_one_paragraph_not_a_traceback():
    with pytest.raises(GLUnavailableError) as exc:
        GLContext(backend="no-such-backend")
    msg = str(exc.value)
    assert "libegl1" in msg and "libgl1-mesa-dri" in msg
    assert "\n" not in msg
