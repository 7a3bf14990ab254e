"""3D stage (paper section IV-C, IV): lifting 2D samples to 3D, the primary's consistency check and
refit, and the secondary branches' connection test, merging and pruning."""
