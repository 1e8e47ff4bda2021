"""Each pack's life across flights: flights as records, a health point per flight per pack, the
trend and retirement forecast across flights, and ingesting a fleet's logs (docs/packs.md).

Core (pure): :mod:`flights` (where a flight begins and ends), :mod:`health` (a flight's health
point from its current/voltage/temperature series), :mod:`trend` (fade and growth against
equivalent cycles, the retirement forecast, the next flight's priors), :mod:`identity` (which pack
it is). Shell: :mod:`records` (SQLite), :mod:`logs` (reading tlog/.bin/.ulg into series),
:mod:`ingest` (many logs on a process pool or a Dask cluster), :mod:`cli`.
"""
