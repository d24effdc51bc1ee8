"""drake_cfvol's bundled co-manipulation scenarios."""
