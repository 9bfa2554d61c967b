"""network: the feed-forward model, losses, training and inference (torch). Not yet implemented."""
