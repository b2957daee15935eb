"""demo stage: the whole chain in one command (``gprm demo``), resumable; see
:mod:`gprm.demo.pipeline`."""
