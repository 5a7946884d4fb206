"""The documentation site's build-time generators (``docs/hooks.py``, mkdocs.yml): a package so that
this tree's ``docs`` wins over any installed module of that name."""
