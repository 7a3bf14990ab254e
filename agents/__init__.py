"""Decision makers (rotation policies) with the stable-baselines3 ``predict`` signature.

``factory.make_agent(spec, env)`` builds any of them from a spec; ``models/`` holds the shipped
learned policies (package data), each with a card, played as ``ppo:NAME``.
"""
