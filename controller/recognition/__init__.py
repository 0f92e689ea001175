"""Error recognition: Hu-moment features, the error library and its nearest-neighbour matcher (pure)."""
