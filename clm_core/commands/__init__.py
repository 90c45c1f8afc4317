"""Sub-commands of the ``clm`` command line.

Each module here defines ``register(subparsers)``, which adds its parser and
sets ``func`` to a callable ``run(args) -> int`` whose docstring is the
command's help (:func:`clm_core.commands._common.add_command`).
:mod:`clm_core.cli` discovers the modules; a new command needs no edit elsewhere.
"""
