"""The repository folder imported as the ``stillpoint`` package.

Python finds a folder named ``stillpoint`` in the current directory before an installed package
of that name only when the folder is a regular package; as a bare folder it would become an empty
namespace package and hide the installed one (``stillpoint.read`` missing). So, when the clone is
imported from the folder that holds it (the layout the README sets up, ``shared/`` beside the
clone), this file makes it the same package as the installed one: the product's
``_stillpoint/__init__.py`` is run here, and ``engine/``, ``drivers/``, ``tools/`` (and
``_stillpoint/__main__.py``) are found as its subpackages, as pyproject.toml's package-dir maps
them. An installed or editable ``stillpoint`` never imports this file.
"""

import os as _os

_HERE = _os.path.dirname(_os.path.abspath(__file__))
__path__ = [_HERE, _os.path.join(_HERE, "_stillpoint")]
_INIT = _os.path.join(_HERE, "_stillpoint", "__init__.py")
with open(_INIT, encoding="utf-8") as _f:
    exec(compile(_f.read(), _INIT, "exec"))  # noqa: S102 - the package's own __init__
