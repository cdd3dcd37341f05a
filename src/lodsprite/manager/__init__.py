"""The LODManager (Gumbau et al.): continuous-LOD objects sharing LOD snapshots, the
crowd and its walkthrough, the baselines and the reproduction."""
