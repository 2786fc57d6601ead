"""The estimator service without sockets: filter assembly per variant, alignment, detection.

One job: turn decoded samples (:mod:`immukf_sitl.samples`) into estimates and detection events.
May import :mod:`immukf_sitl.estimation`, :mod:`immukf_sitl.models` and the shared records
(:mod:`immukf_sitl.samples`); never pymavlink, sockets, files or argparse.
"""
