"""demo stage: ``gprm demo``, the whole chain on a generated campaign: exactly ``gprm run``
(:mod:`gprm.run`) with a synthetic campaign and synthetic telemetry."""
