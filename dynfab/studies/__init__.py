"""Studies: many runs of one scene on Dask (`dynfab study`): the study file (`file`), one case
on a worker (`case`), the driver (`study`), the gathered table (`table`) and its figures
(`plots`)."""
