"""Experiments and orchestration: run, replay, report, bench, observability, validate-model.

One job: fly, replay and measure. The top of the stack: may import everything in
``immukf_sitl`` and the simulator (``sim``); nothing imports it but the command line.
"""
