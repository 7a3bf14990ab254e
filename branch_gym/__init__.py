"""branch_gym: simulator and learning testbed for active branch scanning in orchard robotics."""
