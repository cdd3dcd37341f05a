"""The LOD server for web pages: ``lodsprite serve --web`` (issue 24).

:mod:`.wire` (the WebSocket framing), :mod:`.scene` (the coarse level and texture a page
draws from), :mod:`.security` (token, Origin, rate, TLS), :mod:`.sessions` (one page's
session), :mod:`.hub` (fair scheduling over the render pool), :mod:`.server` (the aiohttp
application).  The page itself is ``static/``.
"""
