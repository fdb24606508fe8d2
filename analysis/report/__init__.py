"""The analysis report: its figures, parameters, slices, truth comparison and the page that shows them."""
