"""network: the feed-forward model (config, model), data, losses and training (torch)."""
