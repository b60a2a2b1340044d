"""The report wing: the report's tables (:mod:`.statistics`), the self-test against the mini-world's
manifest (:mod:`.selftest`), plots (:mod:`.plots`) and the HTML index (:mod:`.index`)."""
