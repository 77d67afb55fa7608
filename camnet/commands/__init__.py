"""One module per `camnet` sub-command: `add_arguments(parser)` and `run(args) -> int`.

Modules here import only the standard library at top level, so that
`camnet --help` stays fast and a missing optional dependency breaks only the
command that needs it.
"""
