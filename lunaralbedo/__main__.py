"""``python -m lunaralbedo``: the same as the ``lunaralbedo`` command."""
from .cli import main

main()
