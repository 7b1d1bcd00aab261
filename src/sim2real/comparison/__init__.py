"""The paper's comparison: ``sim2real benchmark`` trains, translates and evaluates every method on the
same data and budget (``run.py``), and writes Table 1 (``table.py``) and its report (``figures.py``)."""
