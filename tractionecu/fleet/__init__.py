"""Fleet scale: a season of recordings from many machines, on Dask, into columnar results and one farm map.

``tractionecu fleet replay|diagnose|map|drift SOURCE --out DIR``
(:mod:`tractionecu.cli.fleet`).  The modules:

* :mod:`.sources` — which recordings a SOURCE holds (a directory tree, a manifest CSV or a glob), and
  each one's machine, date and field from its path or the manifest's columns;
* :mod:`.tasks` — one task per recording (replay, diagnosis), its output keyed by the input's content
  hash and the software version, so a re-run skips done work; a failing recording gives a failure
  record, never an exception that stops the run;
* :mod:`.runner` — the tasks on Dask (a local cluster, an existing scheduler, or in-process), retries,
  the progress line;
* :mod:`.store` — the Parquet tables and their schemas;
* :mod:`.merge` — the farm map: per-recording map stores in one frame merged cell by cell (Chan et
  al.'s pairwise combination of count, mean and M2), with the machines and dates per cell;
* :mod:`.drift` — per machine, the trend of the rolling radius, torque gain/offset and ρ_s per field,
  and the machines whose parameters moved beyond their interval.

Dask and pyarrow are the optional extra ``fleet``; the on-board core and the daemon never import this
package.
"""

from __future__ import annotations
