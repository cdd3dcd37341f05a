"""The papers' published numbers, kept once, for side-by-side reports.

Chen, Swan & Kaufman 1999 (:data:`PAPER`), Scoggins, Machiraju & Moorhead 2000
(:data:`PAPER_2000`) and Swan, Arango & Nakshatrala 2002 (:data:`PAPER_2002`).  Reports,
the command line and the reproductions read them from here; nothing else types them.
"""

from __future__ import annotations

#: The paper's headline numbers (§4; 460 frames, ε = 1 px, SGI Power Challenge with
#: InfiniteReality graphics).  Times in ms: the paper's "microseconds" is a typo,
#: as its totals show (383.2 s / 460 frames ≈ 833 ms per full-resolution frame).
PAPER: dict[str, float] = {
    "keyframes": 28,
    "frames": 460,
    "epsilon": 1.0,
    "mean_ms_keyframe": 830,
    "mean_ms_first_sprite": 36,
    "mean_ms_sprite": 15,
    "total_s_full": 383.2,
    "total_s_sprite": 31.1,
    "speedup": 12.32,
    "sprite_frames": 403,
    "first_sprite_frames": 28,
}

PAPER_KEYFRAME_FRACTION = PAPER["keyframes"] / PAPER["frames"]

#: Target for (mean RMSE of LOD-sprite) / (mean RMSE of plain LOD): our reading of the
#: paper's qualitative claim (Figs 13-14) that LOD-sprite is "much closer" to full res.
RMSE_RATIO_TARGET = 0.5

#: Scoggins, Machiraju & Moorhead (2000, §4.2-4.3; dual 600 MHz Pentium III): profile times
#: in minutes, triangle and face counts, and the sphereflake thresholds of Eq. 7 (no CSF)
#: and Eq. 16 (CSF).
PAPER_2000: dict[str, float] = {
    "profile_min_sphere": 17, "profile_min_mountain": 100,
    "snowflake_triangles_full": 9_451_008, "sphere_faces_full": 394_212,
    "mountain_faces_full": 8538, "threshold_nocsf": 1e-6, "threshold_csf": 1e-5,
}

#: Swan, Arango & Nakshatrala (2002, §4; 600 frames, 512² height field, two SGI Onyx over
#: 10BASE-T): per set-up, times in ms.
PAPER_2002: dict[str, dict[str, float]] = {
    "separate": {"client_ms_mean": 61.9, "client_ms_std": 14.8, "sprites_per_keyframe": 34.3,
                 "delta_t_ms_mean": 8940, "production_ms_mean": 2140,
                 "transmission_ms_mean": 2320, "render_ms_mean": 517,
                 "queue_insert_ms_mean": 1590, "viewpoint_wait_ms_mean": 0.06,
                 "queue_retrieve_ms_mean": 25},
    "same_cores": {"client_ms_mean": 256, "client_ms_std": 225},
}

#: Sloan, Cohen & Gortler (1997, §5; SGI Maximum Impact, RE2, O2): Table 1's fill rates
#: (bilinear textured pixels drawn per pixel; "progressive" is Partial Valid, 6x²-3x+3 with
#: x the share of nodes partly valid; "full" is §5.1's "each pixel has to be textured 3
#: times"), its texture load and locality, and the set-up.
PAPER_1997: dict = {
    "fill_rate": {"full": 3.0, "subsample": 3.0, "fixed": 2.25, "arbitrary": 3.0,
                  "progressive": "6x²−3x+3", "line": 2.0, "projective": 1.5},
    "texture_load": {"full": "(all nodes)", "subsample": "poor", "fixed": "good",
                     "arbitrary": "strong",
                     "progressive": "strong", "line": "good", "projective": "not a factor"},
    "locality": {"full": "(reference)", "subsample": "low", "fixed": "strong",
                 "arbitrary": "good",
                 "progressive": "strong", "line": "strong", "projective": "strong"},
    "st": 32, "uv": 256, "size": 512, "full_fps": 30, "critical_target_fps": 10,
    "texture_mb_re2": 4, "fill_mtex_s_needed": 23.6,
}

#: Gumbau, Ripolles & Chover (§5.3; Athlon 64 3500+, GeForce 6800 Ultra): the scenes and
#: the models.  The paper gives its fps only as plots (Figure 6), no figures in the text.
PAPER_GUMBAU: dict = {
    "objects": 3000, "trees": 100, "ogre_triangles": 1960, "tree_triangles": 97_133,
    "min_fraction": 0.1,
}
