"""The estimator service without sockets: filter assembly per variant, alignment, detection.

One job: turn decoded samples (:mod:`immukf_sitl.samples`) into estimates and detection events
(:class:`~immukf_sitl.service.pipeline.EstimatorPipeline`). May import
:mod:`immukf_sitl.estimation`, :mod:`immukf_sitl.models` and the shared records; never
pymavlink, sockets, files or argparse. ``serve``, ``replay`` and the in-process chain wrap it.
"""
