"""io: every file format the tool reads or writes (campaigns, results, budgets, plans) and the one output-writing path."""
