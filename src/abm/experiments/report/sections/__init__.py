"""The report's section writers, one module per section kind (registered in
:data:`abm.experiments.report.kinds.SECTIONS`)."""
