"""Writers of estimates in formats other tools open (MCAP for Foxglove)."""
