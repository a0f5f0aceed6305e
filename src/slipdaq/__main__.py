from slipdaq.cli import main

raise SystemExit(main())
