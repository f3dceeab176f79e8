"""OPC UA login timing (issue 27, point 5): an unknown user against a wrong password.

A refusal must not tell which user names exist: both cost one PBKDF2-SHA256 with the users'
iteration count (``cnctwin.edge.opcua._UserManager``: a dummy hash for unknown names). This
script measures both, interleaved, ``--n`` times each, beside the accepted login (the same
derivation plus the session) as the baseline, and prints the medians and their ratio; the
acceptance is the ratio within 0.8-1.2. The unit test (tests/edge/test_opcua_security.py)
checks the derivations are the same; the time is measured here, on a quiet machine, not
under a loaded test run.

Run: ``.venv/bin/python benchmarks/bench_opcua_login.py [--n 41 --iterations 200000]``
"""

from __future__ import annotations

import argparse
import platform
import statistics
import time

from cnctwin.edge.opcua import _UserManager, hash_password


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, default=41, help="logins of each kind (41)")
    ap.add_argument("--iterations", type=int, default=200_000,
                    help="PBKDF2 iterations of the users file (200000, the default)")
    args = ap.parse_args()
    um = _UserManager({"operator": hash_password("correct-horse", iterations=args.iterations)},
                      max_failures=10**9)

    def cost(name: str, pw: str) -> float:
        t0 = time.perf_counter()
        um.get_user(None, username=name, password=pw)
        return time.perf_counter() - t0

    unknown, wrong, right = [], [], []
    for i in range(args.n):
        unknown.append(cost(f"nobody{i}", "x"))
        wrong.append(cost("operator", f"wrong{i}"))
        right.append(cost("operator", "correct-horse"))
    mu, mw, mr = (statistics.median(v) * 1e3 for v in (unknown, wrong, right))
    print(f"machine: {platform.machine()}, {platform.python_version()}, "
          f"{args.iterations} PBKDF2-SHA256 iterations, {args.n} logins each (interleaved)")
    print(f"{'login':<22}{'median [ms]':>12}{'p10':>8}{'p90':>8}")
    for label, v in (("unknown user", unknown), ("wrong password", wrong),
                     ("right password (base)", right)):
        q = statistics.quantiles(v, n=10)
        print(f"{label:<22}{statistics.median(v) * 1e3:>12.1f}{q[0] * 1e3:>8.1f}"
              f"{q[-1] * 1e3:>8.1f}")
    ratio = mu / mw
    print(f"unknown / wrong = {ratio:.3f} (acceptance 0.8-1.2: "
          f"{'met' if 0.8 <= ratio <= 1.2 else 'NOT met'}); right / wrong = {mr / mw:.3f}")


if __name__ == "__main__":
    main()
