"""``python -m lunaralbedo.cli``: the same as the ``lunaralbedo`` command."""
from . import main

main()
