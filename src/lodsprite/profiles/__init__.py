"""LOD error profiles: Scoggins, Machiraju & Moorhead (2000), "Enabling LOD matching".

Meshes and their level-of-detail chains (§4.2 sphere snowflakes, §4.3 terrain
mountain), view-dependent error spectra, the LOD error table and the selection
of a level from it at render time.
"""
