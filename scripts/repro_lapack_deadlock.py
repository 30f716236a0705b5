"""Smallest program found that deadlocks XLA:CPU on this 2-core machine (jax/jaxlib 0.10.2).

Two independent *batched* `jnp.linalg.solve` calls in one jitted function. Each lowers to the
LAPACK custom call `lapack_dgetrf_ffi`, which splits a large batch over XLA's intra-op thread
pool (`jax::ParallelBatchMap`) and blocks its calling thread in `BlockingCounter::Wait` until
the pieces finish. XLA's thunk executor runs the two independent factorizations concurrently
on the two pool threads, so both threads wait for work queued behind each other: every thread
parks on a futex at 0 % CPU and the call never returns (native stacks: docs/theory/no_lapack.md).

    python scripts/repro_lapack_deadlock.py            # LAPACK solve: hangs (killed after 60 s)
    python scripts/repro_lapack_deadlock.py --ours     # ppr_jax's pure-XLA solve: finishes

ppr_jax avoids the construct: every solve inside its compiled programs is the plain-XLA
Gaussian elimination of `ppr_jax/_linalg.py`.
"""

import subprocess
import sys

CODE = """
import sys, jax, jax.numpy as jnp
jax.config.update("jax_enable_x64", True)
if sys.argv[1] == "ours":
    from ppr_jax._linalg import solve
else:
    solve = jnp.linalg.solve
n = 48320  # 64 robots x 755 output times, as in a batched scene's post-processing
A = jax.random.normal(jax.random.PRNGKey(0), (2, n, 3, 3)) + 3 * jnp.eye(3)
b = jnp.ones((n, 3))
f = jax.jit(lambda A, b: [jax.vmap(solve)(A[i], b) for i in range(2)])
for rep in range(200):
    jax.block_until_ready(f(A + rep, b))
print("finished")
"""

if __name__ == "__main__":
    which = "ours" if "--ours" in sys.argv else "lapack"
    try:
        r = subprocess.run([sys.executable, "-c", CODE, which], timeout=60, capture_output=True,
                           text=True)
        print(which, ":", r.stdout.strip() or r.stderr.strip()[-500:])
    except subprocess.TimeoutExpired:
        print(which, ": no result after 60 s (deadlocked)")
