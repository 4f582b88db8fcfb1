# SPDX-License-Identifier: Apache-2.0
"""The diagnosis benchmark's generator and judge: not part of the product.

:mod:`~mr_bench.scenarios` (seeded random loops with hidden causes),
:mod:`~mr_bench.verdict` (tolerances, the verdict, the judge) and
:mod:`~mr_bench.information` (what a record can determine of the hidden causes). Used by
``benchmarks/`` and ``test/`` only: nothing in ``mr_ident`` imports them and the package
does not install them. The scripts in ``benchmarks/`` import them as their neighbours;
pytest puts ``benchmarks/`` on ``sys.path`` (``pythonpath`` in setup.cfg).
"""
