"""Decision makers (rotation policies) with the stable-baselines3 ``predict`` signature."""
