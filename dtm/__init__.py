"""The airborne LiDAR -> DTM product: its stages, the helpers they share, and its commands."""
