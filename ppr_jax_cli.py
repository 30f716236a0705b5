"""The `ppr-jax` console script.

It sets equinox's runtime-error mode to NaN before anything imports equinox: the command line
checks every result from the status codes its programs return, so the programs need no host
callbacks (diffrax keeps two on its output times, which the command line validates first), and
without host callbacks JAX's persistent compilation cache can store them: a second run on the
same machine skips compilation. Library users keep equinox's default (raise)."""

import os
import sys


def main() -> int:
    os.environ.setdefault("EQX_ON_ERROR", "nan")
    try:
        from ppr_jax._cli import main as cli_main
    except KeyboardInterrupt:  # while importing: nothing ran yet
        print("ppr-jax: interrupted; kept: nothing written", file=sys.stderr)
        return 130
    # an interrupt ends the process at once after its line (`_exit_at_once`)
    return cli_main(exit_on_interrupt=True)


if __name__ == "__main__":
    sys.exit(main())
