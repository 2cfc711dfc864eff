"""``python -m asap_dsl.cli``: the same entry point as the ``asapc`` command."""

from asap_dsl.cli import exit_as_program, main

exit_as_program(main())
