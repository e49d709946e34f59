"""MCAP logging: topic schemas, the queued writer and the tolerant reader."""
