"""Bundled data loaders (importable as ``clipvol.loaders``); see :mod:`clipvol.loader` for the contract."""
