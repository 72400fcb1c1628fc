"""Monte-Carlo campaigns: trials (:mod:`.trials`), the parallel runner and journal
(:mod:`.runner`), their tables (:mod:`.tables`) and plots (:mod:`.plots`)."""
