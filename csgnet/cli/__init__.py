"""The command modules of ``python -m csgnet``: each registers its subcommands with ``register(sub)``.

* :mod:`.programs`: ``render``, ``generate``, ``demo``;
* :mod:`.parse`: ``parse``;
* :mod:`.tables`: ``evaluate``, ``table4``, ``table6``, ``export-weights``;
* :mod:`.edit`: ``edit``;
* :mod:`.common`: what they share.
"""
