"""Bundled YAML presets, installed as the package data of ``recon.configs``.

Each ``<name>.yaml`` here is a preset for ``--preset <name>``; :mod:`recon.presets` finds them
with :mod:`importlib.resources`, so they work from a checkout and from an installed wheel alike.
"""
