"""Sub-commands of the ``clm`` command line.

Each module here defines ``register(subparsers)``, which adds its parser and
sets ``func`` to a callable ``run(args) -> int``. :mod:`clm_core.cli`
discovers the modules; a new command needs no edit elsewhere.
"""
