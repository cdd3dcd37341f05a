"""The LODManager (Gumbau et al.): continuous-LOD objects sharing LOD snapshots, its crowd and walkthrough, the baselines and the reproduction."""
