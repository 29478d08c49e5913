import sys

try:
    from .cli import main
except KeyboardInterrupt:   # before fusion.cli could say it (its own imports say it themselves)
    import os

    print("error: interrupted", file=sys.stderr)
    sys.stderr.flush()
    os._exit(130)           # at once, as fusion.cli does (fusion.cli._interrupted_while_loading)

status = main()
if status in (130, 143):
    # An interrupt, said in one line and cleaned up: exit with its status at once. Through
    # sys.exit, `python -m fusion` now and then died by its own SIGINT instead (exit -2; 4 of 54
    # interrupts while the filter loads during the vision): CPython 3.11 marks a KeyboardInterrupt
    # as unhandled when it ends any code run by PyRun_* (run_eval_code_obj), also one nested in
    # a library's import, and Py_RunMain, which `-m` returns through, then kills the process
    # with SIGINT whatever the program did with the interrupt. (`vifusion`, a script, exits in
    # Py_Exit and never gets there.)
    import os

    sys.stdout.flush()
    sys.stderr.flush()
    os._exit(status)
sys.exit(status)
