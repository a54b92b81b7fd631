"""The command functions of ``abm``, one module per command group (their parsers: ``abm.cli.<group>``). Each
module imports the library it drives at module level; :func:`abm.cli.main` imports only the one a command needs.
"""
