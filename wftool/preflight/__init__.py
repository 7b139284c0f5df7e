"""`wftool preflight`: does control change hands only as the board's configuration says? The
board's settings read and checked (`settings`), then the OBC played failing in every way on
the FSP port (`obc`, `scenarios`) while MSP shows what the FC does (`watcher`); the report
has a line per check, passed, failed or not checked (`report`). `run` is one run on a board,
`virtual` one on the virtual FC configured as a board that flies.
"""
