"""Parameters from measured curves (`dynfab fit`, docs/model.md "Fitting"): the curve file
(`data`), what each model offers a fit (`models`), the least-squares search (`fit`), its exact
sensitivities (`sensitivity`), several starts on Dask (`starts`) and its figures (`plots`)."""
