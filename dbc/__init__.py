"""The bus contract, ``tractionecu.dbc``: installed as the package ``tractionecu.contract``.

This directory is the one place of the DBC; ``pyproject.toml`` maps the
package ``tractionecu.contract`` onto it, so an installed (or editable)
package reads the file with :mod:`importlib.resources`
(:func:`tractionecu.bus.dbc.package_dbc_path`).
"""
