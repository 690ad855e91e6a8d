"""A study's report: matplotlib figures (``figures``), the report's content from the study's artifacts
(``study_report``) and the Typst template typeset to PDF (``typeset``)."""
