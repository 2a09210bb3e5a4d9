from skelfuse.cli import main

raise SystemExit(main())
