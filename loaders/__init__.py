"""Bundled data loaders (importable as ``clipvol.loaders``); see :mod:`clipvol.paging.loader` for the contract."""
