"""``make bench``: the studies behind the documentation's numbers (:mod:`benchmarks.run`) and the page written from their CSVs (:mod:`benchmarks.report`)."""
