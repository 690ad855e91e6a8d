"""Ball-screw preload design with CasADi: the design NLP, its optimum and Pareto fronts (``preload``), the
least-friction preload schedule (``schedule``) and the design study that puts them together (``study``)."""
