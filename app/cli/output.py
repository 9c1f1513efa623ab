"""Where the ``activetouch`` commands print (one pair of consoles for every command).

* :data:`results` — stdout: what a command produces, when it is not ``--json``.
* :data:`messages` — stderr: progress, status lines, warnings and errors.

Both soft-wrap (a long path or action is never folded mid-word when redirected). Redirected,
Rich would draw tables 80 columns wide and fold every row, so :data:`results` is 120 wide then.
Values interpolated into a printed string must go through ``rich.markup.escape`` or carry a
numeric format spec: Rich reads ``[...]`` as markup (a path ``run[final].csv`` would lose
``[final]``, an array ``[nan 1.]`` vanishes, ``[/b]`` raises). ``tests/app/test_cli_markup.py``
checks every f-string handed to Rich in ``app/``.
"""

from __future__ import annotations

import sys

from rich.console import Console

results = Console(soft_wrap=True, width=None if sys.stdout.isatty() else 120)
messages = Console(stderr=True, soft_wrap=True)
