"""The MAVLink edge: every byte on the wire and every message <-> record conversion.

One job: talk MAVLink. The only package that imports pymavlink (through
:mod:`immukf_sitl.mavlink.wire`, which sets MAVLink 2 and the dialect once); the sim's emitter
and fault proxy are its only other users of pymavlink objects. :mod:`~immukf_sitl.mavlink.codec`
converts messages to and from :mod:`immukf_sitl.samples`; :mod:`~immukf_sitl.mavlink.flightlog`
reads and merges tlogs; :mod:`~immukf_sitl.mavlink.serve` is the service loop around
:class:`~immukf_sitl.service.pipeline.EstimatorPipeline`. May import the service, the models,
the estimation core and the shared records; never the experiments.
"""
