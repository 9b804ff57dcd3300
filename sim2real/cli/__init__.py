"""The ``sim2real`` command: thin subcommands over the library (see ``main.COMMANDS``)."""
